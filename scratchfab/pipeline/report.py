"""``JOB/report.html``: one self-contained page a person reads after a run.

Everything is read back from the job folder (SPEC section 6), so the report shows what
the stages actually wrote. Images are inlined as data URIs; numbers that come from
``verify/metrics.json`` carry ``data-metric`` attributes so tests can compare them.
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
from pathlib import Path
from typing import Any

from scratchfab.fileio import write_text
from scratchfab.model.job import JobLayout

_MIME = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".svg": "image/svg+xml"}

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px;color:#222}
h1{margin-bottom:0}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
.row{display:flex;flex-wrap:wrap;gap:1em}.card{border:1px solid #ddd;padding:.5em;border-radius:4px}
.card img{image-rendering:pixelated;width:256px;display:block}
table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
.bad{color:#b00;font-weight:bold}.ok{color:#070}.wide img{width:auto;max-width:640px}
.muted{color:#777}
"""

# Runs in the page: reports whether every image decoded, for people and for tests.
_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  var el = document.getElementById('image-check');
  el.textContent = 'images decoded: ' + (imgs.length - bad.length) + '/' + imgs.length;
  el.setAttribute('data-total', imgs.length);
  el.setAttribute('data-decoded', imgs.length - bad.length);
});
"""


def _img(path: Path, alt: str, css: str = "") -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    mime = _MIME.get(path.suffix.lower(), "application/octet-stream")
    cls = f' class="{css}"' if css else ""
    return f'<img{cls} alt="{html.escape(alt)}" src="data:{mime};base64,{data}">'


def _fmt(value: Any, digits: int = 3) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return "–"
        if math.isinf(value):
            return "∞"
        return f"{value:.{digits}f}"
    return html.escape(str(value))


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _views_section(job: Path, metrics: dict[str, Any] | None) -> str:
    layout = JobLayout(job)
    targets = sorted(layout.design.targets_dir.glob("*.png"))
    if not targets:
        return "<p class='muted'>design has not run.</p>"
    parts = []
    for target in targets:
        name = target.stem
        cards = [f"<div class='card'>target<br>{_img(target, f'{name} target')}</div>"]
        for label, folder in (
            ("optimized render", layout.optimize_renders),
            ("verify render", layout.verify_dir),
        ):
            png = folder / f"{name}.png"
            if png.is_file():
                cards.append(f"<div class='card'>{label}<br>{_img(png, f'{name} {label}')}</div>")
        feas = layout.design.feasibility_png(name)
        if feas.is_file():
            cards.append(
                f"<div class='card'>feasibility<br>{_img(feas, f'{name} feasibility')}</div>"
            )
        parts.append(f"<h3>view {html.escape(name)}</h3><div class='row'>{''.join(cards)}</div>")
    return "\n".join(parts) + _metrics_table(metrics)


def _metrics_table(metrics: dict[str, Any] | None) -> str:
    if not metrics or "views" not in metrics:
        return "<p class='muted'>verify-render has not run: no metrics.</p>"
    views = metrics["views"]
    names = list(views)
    head = "<tr><th>view</th><th>rho_kk</th><th>PSNR (dB)</th><th>rel. L2 vs render</th><th>spp</th><th>seconds</th></tr>"
    rows = []
    for k in names:
        v = views[k]
        cells = []
        for key, digits in (("rho", 3), ("psnr", 2), ("rel_l2", 4), ("spp", 0), ("seconds", 1)):
            value = v.get(key)
            attr = (
                f' data-metric="{html.escape(k)}.{key}" data-value="{value}"'
                if value is not None
                else ""
            )
            cells.append(f"<td{attr}>{_fmt(value, digits) if value is not None else '–'}</td>")
        rows.append(f"<tr><th>{html.escape(k)}</th>{''.join(cells)}</tr>")
    matrix_rows = []
    for k in names:
        cells = []
        for j in names:
            x = views[k].get("crosstalk", {}).get(j)
            if j == k or x is None:
                cells.append("<td>–</td>")
            else:
                cls = "bad" if x > 0.2 else "ok"
                cells.append(
                    f'<td class="{cls}" data-metric="{html.escape(k)}.crosstalk.{html.escape(j)}" '
                    f'data-value="{x}">{_fmt(x)}</td>'
                )
        matrix_rows.append(f"<tr><th>{html.escape(k)}</th>{''.join(cells)}</tr>")
    header = "".join(f"<th>{html.escape(j)}</th>" for j in names)
    return (
        f"<h3>metrics (verify-render)</h3><table>{head}{''.join(rows)}</table>"
        f"<h3>crosstalk x<sub>kj</sub> (row k shows image j)</h3>"
        f"<table><tr><th></th>{header}</tr>{''.join(matrix_rows)}</table>"
    )


def _optimize_section(job: Path) -> str:
    layout = JobLayout(job)
    out = []
    for png in (layout.loss_png,):
        if png.is_file():
            out.append(f"<div class='card wide'>{_img(png, 'loss curve')}</div>")
    log = layout.optimize_log
    if log.is_file():
        with log.open(encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
        if rows:
            last = rows[-1]
            cells = "".join(
                f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                for k, v in last.items()
            )
            out.append(f"<div class='card'>last logged iteration<table>{cells}</table></div>")
    return (
        f"<div class='row'>{''.join(out)}</div>"
        if out
        else "<p class='muted'>optimize has not run.</p>"
    )


def _verify_extras(job: Path) -> str:
    gifs = sorted(JobLayout(job).verify_dir.glob("*.gif"))
    if not gifs:
        return "<p class='muted'>no sweep animation (verify --sweep).</p>"
    cards = "".join(f"<div class='card'>{g.stem}<br>{_img(g, g.stem)}</div>" for g in gifs)
    return f"<p>What a viewer walking past the board sees (verify-render --sweep).</p><div class='row'>{cards}</div>"


def _toolpath_section(job: Path) -> str:
    layout = JobLayout(job)
    data = _read_json(layout.toolpath_json)
    parts = []
    preview = layout.toolpath_preview
    if preview.is_file():
        parts.append(f"<div class='card wide'>{_img(preview, 'toolpath preview')}</div>")
    stats = (data or {}).get("statistics") if isinstance(data, dict) else None
    if isinstance(stats, dict):
        cells = "".join(
            f"<tr><th>{html.escape(str(k))}</th><td data-stat='toolpath.{html.escape(str(k))}'>{_fmt(v, 1)}</td></tr>"
            for k, v in stats.items()
            if not isinstance(v, dict | list)
        )
        parts.append(f"<div class='card'><table>{cells}</table></div>")
    return (
        f"<div class='row'>{''.join(parts)}</div>"
        if parts
        else "<p class='muted'>toolpath has not run.</p>"
    )


def gcode_statistics(path: Path) -> dict[str, Any]:
    """The exporter's statistics of a G-code file, plus its G0 and G1 counts."""
    from scratchfab.export.gcode import gcode_stats

    lines = path.read_text(encoding="utf-8").splitlines()
    stats = gcode_stats(lines)
    words = [ln.split(";")[0].split("(")[0].upper() for ln in lines]
    extent = {
        k.removesuffix("_mm").upper(): f"{v[0]:g} .. {v[1]:g} mm"
        for k, v in stats["bbox"].items()
        if v is not None
    }
    return {
        "lines": stats["lines"],
        "bytes": stats["bytes"],
        "longest_line": stats["max_line_length"],
        **{f"{axis} range": text for axis, text in extent.items()},
        "G0": sum(1 for w in words if w.startswith("G0 ") or w == "G0"),
        "G1": sum(1 for w in words if w.startswith("G1 ") or w == "G1"),
    }


def _export_section(job: Path) -> str:
    layout = JobLayout(job)
    files = layout.export_files()
    if not files:
        return "<p class='muted'>export has not run.</p>"
    items = "".join(f"<li>{html.escape(f.name)} ({f.stat().st_size} bytes)</li>" for f in files)
    gcode = layout.export_file("gcode")
    table = ""
    if gcode.is_file():
        stats = gcode_statistics(gcode)
        table = (
            "<table>"
            + "".join(
                f"<tr><th>{k}</th><td data-stat='gcode.{k}'>{v}</td></tr>" for k, v in stats.items()
            )
            + "</table>"
        )
    return f"<ul>{items}</ul>{table}"


def _stream_section(job: Path) -> str:
    """What the journal's last run of streams (since its last fresh start) acknowledged."""
    from scratchfab.errors import ConfigError
    from scratchfab.machine.sender_journal import (
        default_journal_path,
        done_blocks,
        interrupted,
        read_journal,
    )

    journal = default_journal_path(JobLayout(job).export_file("gcode"))
    if not journal.is_file():
        return "<p class='muted'>not streamed.</p>"
    try:
        events = read_journal(journal)
        starts = [ev for ev in events if ev.get("ev") == "start"]
        if not starts:
            return "<p class='muted'>not streamed (the journal is empty).</p>"
        sha256 = str(starts[-1].get("sha256"))
        done = len(done_blocks(events, sha256, journal, recut_unclosed=False))
    except ConfigError as exc:
        return f"<p class='bad'>{html.escape(str(exc))}</p>"
    total = starts[-1].get("blocks")
    state = "unfinished (the next run resumes it)" if interrupted(events, sha256) else "finished"
    return (
        f"<p><span data-stat='stream.acknowledged'>{done}</span> of "
        f"<span data-stat='stream.lines'>{total}</span> G-code lines acknowledged by the "
        f"controller since the last fresh start; {state} (journal.jsonl).</p>"
    )


def _setup_step(job: Path) -> str:
    """How to set the machine up: the profile's placement, and README step 5."""
    text = (
        "Set the machine up as README step 5 (<b>Cut.</b>) says for your profile: the G-code "
        "moves in the profile's own coordinates"
    )
    from scratchfab.errors import ConfigError
    from scratchfab.toolpath import Toolpath

    try:
        profile = Toolpath.load(JobLayout(job).toolpath_json).profile
    except ConfigError:  # no toolpath yet, or a damaged one: the pointer alone
        return text + "."
    x, y = profile.board.offset_mm
    return text + (
        f" ('{html.escape(profile.name)}'): the board's {html.escape(profile.board.origin)} "
        f"corner at X <span data-stat='setup.x'>{x:g}</span> Y "
        f"<span data-stat='setup.y'>{y:g}</span>, the tool cutting at Z "
        f"<span data-stat='setup.z'>{profile.z.engrave_mm:g}</span> mm. Make both true on "
        "your machine before streaming (bundled grbl-3018-diamond: machine coordinates after "
        "homing, G54 offset cleared; do not zero the work coordinates on the board)."
    )


def _next_steps(job: Path, metrics: dict[str, Any] | None) -> str:
    steps = []
    if metrics and any(v.get("rho", 1.0) < 0.8 for v in metrics.get("views", {}).values()):
        steps.append(
            "A view falls short: run optimize longer, add scratches, or move the views apart."
        )
    steps += [
        "Check the toolpath preview: every stroke inside the board, travel moves sensible.",
        _setup_step(job),
        f"Dry-run first: <code>scratchfab stream {html.escape(str(JobLayout(job).export_file('gcode')))} --port PORT --check</code>.",
        "Then stream for real; after a dropped cable, rerun the same command with <code>--resume</code>.",
    ]
    return "<ol>" + "".join(f"<li>{s}</li>" for s in steps) + "</ol>"


def write_report(job: Path, title: str = "scratchfab job") -> Path:
    """Write ``JOB/report.html`` from what the stages left in the job folder."""
    metrics = _read_json(JobLayout(job).verify_metrics)
    body = [
        f"<h1>{html.escape(title)}</h1><p class='muted'>{html.escape(str(job.resolve()))}</p>",
        "<p id='image-check' class='muted'>images: checking…</p>",
        "<h2>Views</h2>",
        _views_section(job, metrics),
        "<h2>Optimization</h2>",
        _optimize_section(job),
        "<h2>Beyond the design light</h2>",
        _verify_extras(job),
        "<h2>Toolpath</h2>",
        _toolpath_section(job),
        "<h2>Export</h2>",
        _export_section(job),
        "<h2>Stream</h2>",
        _stream_section(job),
        "<h2>What to do next</h2>",
        _next_steps(job, metrics),
    ]
    page = (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style>"
        f"<script>{_SCRIPT}</script></head><body>{''.join(body)}</body></html>\n"
    )
    out = JobLayout(job).report_html
    write_text(out, page)
    return out
