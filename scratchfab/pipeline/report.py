"""``JOB/report.html``: one self-contained page a person reads after a run.

Everything is read back from the job folder (SPEC section 6), so the report shows what
the stages actually wrote; the pipeline adds only what the folder does not hold (its
``[stream]`` port and ``[verify] min_rho``). The page opens with a verdict (ready to cut
or not, and why), says where to stand, and picks its next steps from the job's state.
Images are inlined as data URIs so the page survives moving the folder; numbers from
``verify/metrics.json`` carry ``data-metric`` attributes so tests can compare them.
"""

from __future__ import annotations

import base64
import csv
import hashlib
import html
import json
import math
import os
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from scratchfab.bundled import bundled_name
from scratchfab.console import command_line, duration_text
from scratchfab.design.stand import side, stand_text
from scratchfab.errors import ConfigError
from scratchfab.fileio import decode_json, write_text
from scratchfab.machine.profile import MachineProfile
from scratchfab.metrics import CROSSTALK_MEANING, rho_text
from scratchfab.model.design import Design, Vec3, load_design, polar_from_position
from scratchfab.model.job import JobLayout
from scratchfab.verify.gate import gate_applies
from scratchfab.verify.noise import diff_noise_advice, noise_advice, noise_explains
from scratchfab.verify.outshine import outshine_advice, shoulder_shares

if TYPE_CHECKING:
    from scratchfab.machine.sender_program import Program

_MIME = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".svg": "image/svg+xml"}

#: How wide (CSS pixels) the report shows a picture, and a wide one at most.
PICTURE_PX = 256
WIDE_PX = 640

_STYLE = (
    """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px;color:#222}
h1{margin-bottom:0}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
.row{display:flex;flex-wrap:wrap;gap:1em}
figure{border:1px solid #ddd;padding:.5em;border-radius:4px;margin:0;max-width:300px}
"""
    f"figure img{{image-rendering:pixelated;width:{PICTURE_PX}px;display:block}}\n"
    f"figure.wide{{max-width:{WIDE_PX + 20}px}}\n"
    f"figure.wide img{{width:auto;max-width:{WIDE_PX}px;image-rendering:auto}}\n"
    """.views figure{max-width:none}
figure.full{max-width:none;width:100%}
figure.full img{width:100%;max-width:none;image-rendering:auto}
figcaption{font-size:.85em;color:#444;margin-top:.3em}
table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th[scope=row],td.text{text-align:left}
.bad{color:#b00;font-weight:bold}.ok{color:#070}.warn{color:#a60;font-weight:bold}
.muted{color:#777}
.verdict{border:3px solid;border-radius:6px;padding:.6em 1em;margin-top:1em}
.verdict.ready{border-color:#070;background:#f2fbf2}.verdict.notready{border-color:#b00;background:#fdf2f2}
.verdict h2{margin:0 0 .4em 0;border:0}.verdict ul{list-style:none;padding-left:0;margin:0}
.verdict li{margin:.2em 0}
"""
)

# Runs in the page: counts the images that decoded, for tests (nothing is shown).
_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  var el = document.getElementById('image-check');
  el.setAttribute('data-total', imgs.length);
  el.setAttribute('data-decoded', imgs.length - bad.length);
});
"""

# Symbol and word of each check status: readable without colour.
_MARK = {"ok": "✔ ok", "fail": "✘ no", "warn": "⚠ check", "info": "ℹ info"}
_CSS = {"ok": "ok", "fail": "bad", "warn": "warn", "info": "muted"}
# A stage's manifest status as the verdict says it.
# "running" after the run ended: the process died (killed) before it could say.
_STAGE_STATUS = {"interrupted": "was interrupted", "running": "did not finish"}


def _absent(stage: str, stopped: Mapping[str, str], detail: str = "") -> str:
    """The muted line for a section whose stage left no output.

    ``stopped`` maps a stage that failed, was interrupted or died to what the verdict
    says of it: such a stage ran, so "has not run" would contradict its line.
    """
    said = (
        f"{stage} {stopped[stage]} (see the verdict above)"
        if stage in stopped
        else (f"{stage} has not run")
    )
    return f"<p class='muted'>{html.escape(said)}{detail}.</p>"


Status = Literal["ok", "fail", "warn", "info"]


@dataclass(frozen=True)
class _Check:
    """One line of the verdict box: ``html`` is the line, ``reason`` its short form.

    ``not_run``: the stage whose output is missing (the line says it has not run), left
    out where the manifest says that stage failed or stopped (its own line says so).
    """

    status: Status
    html: str
    reason: str = ""
    fix: str = ""
    not_run: str = ""
    stage: str = ""


@dataclass(frozen=True)
class _Stream:
    """What the journal says about streaming the job's current G-code.

    ``kind``: "none" (not streamed), "emulator", "real" (the pipeline's port is a
    machine), "unknown" (streamed, but no pipeline port says where to).
    """

    kind: Literal["none", "emulator", "real", "unknown"]
    finished: bool = False
    done: int = 0
    total: int = 0
    port: str | None = None
    note: str = ""
    session: Literal["latest", "earlier", "unsure"] = "latest"


@dataclass(frozen=True)
class _Stopped:
    """A stage the manifest says failed, was interrupted or died.

    ``said``: as the verdict says it ("failed", "was interrupted"); ``why``: the reason
    the manifest records ("" without); ``started``: when that run of it began (None:
    not recorded, a manifest of an earlier scratchfab).
    """

    said: str
    why: str = ""
    started: str | None = None


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    mime = _MIME.get(path.suffix.lower(), "application/octet-stream")
    return f'<img alt="{html.escape(alt)}" src="data:{mime};base64,{data}">'


def _figure(
    path: Path,
    alt: str,
    caption: str,
    wide: bool = False,
    width: int | None = None,
    full: bool = False,
) -> str:
    """A picture and its caption in a box.

    ``wide``: the picture at its own size (up to WIDE_PX), else PICTURE_PX wide; ``width``:
    the box's inner width in pixels (else as the picture and the caption ask); ``full``:
    the page's width, smoothly scaled (a large drawing whose small text must stay legible).
    """
    cls = " class='full'" if full else " class='wide'" if wide else ""
    style = f" style='width:{width}px'" if width is not None else ""
    return f"<figure{cls}{style}>{_img(path, alt)}<figcaption>{caption}</figcaption></figure>"


def _shown_width(path: Path, wide: bool) -> int:
    """The width the report shows the picture ``path`` at (a wide one: its own, capped)."""
    if not wide:
        return PICTURE_PX
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():  # only the size is read, never the pixels
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as image:
                return min(WIDE_PX, image.width)
    except Image.DecompressionBombError:  # more pixels than Pillow opens: wider than shown
        return WIDE_PX
    except OSError:
        return PICTURE_PX


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
        return decode_json(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _recorded_gate(path: Path) -> float | None:
    """The ``min_rho`` verify recorded in its ``metrics.json``, read as the run's result is.

    None without one, or where the gate is damaged.
    """
    from scratchfab.pipeline.runner import VerifyMetrics  # runner imports this module

    try:
        recorded = VerifyMetrics.read(path)
    except ConfigError:
        return None
    return recorded.min_rho if recorded is not None else None


def _link(job: Path, path: Path) -> str:
    rel = path.relative_to(job).as_posix()
    return f"<a href='{html.escape(rel)}'><code>{html.escape(rel)}</code></a>"


def _code(text: str) -> str:
    return f"<code>{html.escape(text)}</code>"


# --- the design's geometry --------------------------------------------------------


def _read_design(job: Path) -> Design | None:
    """The job's resolved design (no pictures are read, so a moved job works), or None."""
    try:
        return load_design(JobLayout(job).design.design_toml, require_views=False)
    except ConfigError:
        return None


def _vec3(values: Any) -> Vec3:
    return (float(values[0]), float(values[1]), float(values[2]))


def _stand_section(design: Design | None, stopped: Mapping[str, str]) -> str:
    if design is None or not design.views:
        return _absent("design", stopped)
    items = []
    for view in design.views:
        name = view.name
        az, el, dist = polar_from_position(_vec3(view.camera_position))
        items.append(
            f"<li data-stand='{html.escape(name)}' data-azimuth='{az:.3f}' "
            f"data-elevation='{el:.3f}' data-distance='{dist:.3f}'><b>{html.escape(name)}</b>: "
            f"{html.escape(stand_text(design, view))}.</li>"
        )
    return (
        "<p>Angles are from the board's front (its normal) with its top edge up; distances "
        "from its centre. Each picture shows only from its own place, under a small light "
        "where the design puts it.</p>"
        f"<ul>{''.join(items)}</ul>"
    )


def _view_order(design: Design | None, metrics: dict[str, Any] | None, job: Path) -> list[str]:
    """The views in the design's order (else metrics.json's, else the targets' names)."""
    if design is not None and design.views:
        return [view.name for view in design.views]
    if metrics and isinstance(metrics.get("names"), list):
        return [str(n) for n in metrics["names"]]
    if metrics and isinstance(metrics.get("views"), dict):
        return list(metrics["views"])
    return sorted(p.stem for p in JobLayout(job).design.targets_dir.glob("*.png"))


# --- the verdict ------------------------------------------------------------------


def _stopped_stages(job: Path) -> dict[str, _Stopped]:
    """Stages whose latest run failed, stopped or never finished (from the manifest)."""
    manifest = _read_json(job / "manifest.json")
    if not isinstance(manifest, dict) or not isinstance(manifest.get("stages"), dict):
        return {}
    stopped = {}
    for stage, entry in manifest["stages"].items():
        if not isinstance(entry, dict) or entry.get("status") == "done":
            continue
        status = str(entry.get("status"))
        started = entry.get("started")
        stopped[stage] = _Stopped(
            _STAGE_STATUS.get(status, status),
            str(entry.get("reason") or ""),
            started if isinstance(started, str) else None,
        )
    return stopped


def _stage_checks(stopped: Mapping[str, _Stopped]) -> list[_Check]:
    """The verdict's line for each of :func:`_stopped_stages` before stream."""
    return [
        _Check(
            "fail",
            # Phrased as a claim like every other line, so that "✘ no" reads as its answer.
            f"every stage finished: stage {html.escape(stage)} {html.escape(it.said)}"
            + (f": {html.escape(it.why)}" if it.why else "")
            + " (files after it may be from an earlier run)",
            f"stage {stage} {it.said}",
            f"Fix what stage {html.escape(stage)} reports above.",
            stage=stage,
        )
        for stage, it in stopped.items()
        if stage != "stream"  # its own line (_stream_check)
    ]


def _feasibility_checks(data: Any) -> list[_Check]:
    """The verdict's lines from ``design/feasibility.json`` (``data``, None if unreadable)."""
    if not isinstance(data, dict):
        return [
            _Check(
                "fail", "feasibility: design has not run", "design has not run", not_run="design"
            )
        ]
    errors = [str(e) for e in data.get("errors", [])]
    warnings = [str(w) for w in data.get("warnings", [])]
    checks = [
        _Check(
            "fail",
            f"feasibility: {html.escape(e)}",
            "feasibility error",
            "Change the design as the feasibility error above advises (where the views or "
            "the light stand, or the tool).",
        )
        for e in errors
    ]
    checks += [_Check("warn", f"feasibility: {html.escape(w)}") for w in warnings]
    if not errors and not warnings:
        checks.append(
            _Check(
                "ok",
                "feasibility: the tool reaches every view, no view too close to another, "
                "no glint of the bare board",
            )
        )
    return checks


def _glint_shares(data: Any) -> dict[str, float]:
    """Per view, the share of the board where the bare board glints (``feasibility.json``)."""
    views = data.get("views") if isinstance(data, dict) else None
    if not isinstance(views, dict):
        return {}
    shares = {}
    for name, entry in views.items():
        share = entry.get("glint_fraction") if isinstance(entry, dict) else None
        if isinstance(share, int | float) and share > 0:
            shares[str(name)] = float(share)
    return shares


#: The next step for a view that falls short where the bare board outshines its grooves.
_OUTSHONE_FIX = (
    "The bare board outshines the grooves of a view that looks too little like its target "
    "(the feasibility warning above says where): do as that view's line says; optimizing "
    "longer does not help."
)


def _rho_checks(
    names: list[str],
    metrics: dict[str, Any] | None,
    min_rho: float | None,
    glint: dict[str, float] | None = None,
    feasibility: Any = None,
) -> list[_Check]:
    """One line per view on its rho.

    ``glint`` (:func:`_glint_shares`) and ``feasibility`` (``design/feasibility.json``)
    give the advice where the bare board outshines a failing view's grooves.
    """
    glint = glint or {}
    shoulders = shoulder_shares(feasibility)
    views = (metrics or {}).get("views")
    if not isinstance(views, dict):
        return [
            _Check(
                "fail",
                "the views look like their targets: verify has not run",
                "verify has not run",
                not_run="verify",
            )
        ]
    checks = []
    for name in names:
        entry = views.get(name)
        entry = entry if isinstance(entry, dict) else {}
        rho = entry.get("rho")
        label = f"{html.escape(name)} looks like its target: rho_kk"
        noisy = noise_advice(entry, min_rho, "[verify] spp =")
        noisy_html = f"; {html.escape(noisy)}" if noisy else ""
        if rho is None:
            checks.append(_Check("fail", f"{label} missing", f"{name}: no rho"))
        elif not gate_applies(min_rho):  # -1: the gate is off, nothing passes it
            why = "no min_rho set" if min_rho is None else f"min_rho {min_rho:g}: no gate"
            checks.append(
                _Check("info", f"{label} {rho_text(rho)} (1 = perfect; {why}){noisy_html}")
            )
        elif rho >= min_rho:
            checks.append(
                _Check(
                    "ok",
                    f"{label} {rho_text(rho, min_rho)} ≥ {min_rho:g} ([verify] min_rho; "
                    f"1 = perfect){noisy_html}",
                )
            )
        elif noise_explains(entry, min_rho):
            checks.append(
                _Check(
                    "fail",
                    f"{label} {rho_text(rho, min_rho)} &lt; {min_rho:g} ([verify] min_rho; "
                    f"1 = perfect){noisy_html}",
                    f"{name} rho {rho_text(rho, min_rho)} below {min_rho:g} in a noisy render",
                    "The verify render is too noisy to judge a view: raise [verify] "
                    "<code>spp</code> as the line above says (the board itself may be good "
                    "enough).",
                )
            )
        else:
            outshone = _outshone(name, glint, shoulders, feasibility)
            why = "".join(f"; {a}" for a in outshone)
            checks.append(
                _Check(
                    "fail",
                    f"{label} {rho_text(rho, min_rho)} &lt; {min_rho:g} ([verify] min_rho; "
                    f"1 = perfect){html.escape(why)}{noisy_html}",
                    f"{name} rho {rho_text(rho, min_rho)} below {min_rho:g}"
                    + (" (the bare board outshines its grooves)" if outshone else ""),
                    _OUTSHONE_FIX
                    if outshone
                    else f"A view looks too little like its target: {_RAISE}. To cut the "
                    "board as it is, lower [verify] <code>min_rho</code> (-1 never stops the "
                    "run).",
                )
            )
    return checks + _weakest_check(names, views, min_rho, glint, shoulders, feasibility)


#: What raises a view's rho where the bare board does not outshine its grooves.
_RAISE = (
    "run optimize longer ([optimize] iterations), add scratches ([scratch] count), or move "
    "the views further apart"
)


def _outshone(
    name: str, glint: Mapping[str, float], shoulders: Mapping[str, float], feasibility: Any
) -> list[str]:
    """Verify's clauses where the bare board outshines view ``name``'s grooves ([] if not)."""
    return outshine_advice(
        {name: glint[name]} if name in glint else {},
        {name: shoulders[name]} if name in shoulders else {},
        feasibility,
        "[scratch] count =",
    )


def _weakest_check(
    names: list[str],
    views: Mapping[str, Any],
    min_rho: float | None,
    glint: Mapping[str, float],
    shoulders: Mapping[str, float],
    feasibility: Any,
) -> list[_Check]:
    """Where every view passes, the one that looks least like its target, and how to raise it.

    A warning (the board stays ready to cut) where that view's rho lies nearer the gate
    than the best view's: one view shows its picture far less clearly than the others.
    Nothing for fewer than two measured views, or where a view fails (its line says it).
    """
    rhos: dict[str, float] = {}
    for name in names:
        rho = (views.get(name) or {}).get("rho")
        if isinstance(rho, int | float) and math.isfinite(rho):
            rhos[name] = float(rho)
    gate = min_rho if gate_applies(min_rho) else None  # -1: no gate
    if len(rhos) < 2 or (gate is not None and any(not r >= gate for r in rhos.values())):
        return []
    weakest = min(rhos, key=rhos.__getitem__)
    best = max(rhos, key=rhos.__getitem__)
    rho, top = rhos[weakest], rhos[best]
    said = (
        f"weakest view: {html.escape(weakest)}, rho_kk "
        f"<span data-stat='weakest.rho'>{rho_text(rho, min_rho)}</span> (the best, "
        f"{html.escape(best)}, {rho_text(top, min_rho)}"
    )
    if gate is None:
        return [_Check("info", said + ")")]
    margin = rho - gate
    said += f"; {margin:.3f} above [verify] min_rho {gate:g})"
    if not margin < top - rho:
        return [_Check("info", said)]
    outshone = _outshone(weakest, glint, shoulders, feasibility)
    how = html.escape("; ".join(outshone)) if outshone else _RAISE  # _RAISE: nothing to escape
    return [
        _Check(
            "warn",
            f"{said}: nearer min_rho than the best view, so {html.escape(weakest)} will show "
            f"its picture least clearly; to raise it, {how}",
            fix=f"The board passes as it is. If view {html.escape(weakest)} should look as "
            f"clear as {html.escape(best)}: {how}.",
        )
    ]


def _crosstalk_check(names: list[str], metrics: dict[str, Any] | None) -> list[_Check]:
    views = (metrics or {}).get("views")
    if not isinstance(views, dict) or len(names) < 2:
        return []
    worst: tuple[float, str, str] | None = None
    for k in names:
        for j, x in (views.get(k, {}).get("crosstalk") or {}).items():
            if x is not None and (worst is None or x > worst[0]):
                worst = (float(x), k, str(j))
    if worst is None:
        return []
    x, k, j = worst
    return [
        _Check(
            "info",
            f"crosstalk: at most {x:.3f} ({html.escape(j)}'s picture showing in view "
            f"{html.escape(k)}, {CROSSTALK_MEANING}). "
            "No crosstalk limit is configured, so it does not decide the verdict.",
        )
    ]


def _toolpath_checks(data: Any) -> list[_Check]:
    """The verdict's lines from ``toolpath/toolpath.json`` (``data``, None if unreadable)."""
    stats = data.get("statistics") if isinstance(data, dict) else None
    if not isinstance(stats, dict):
        return [
            _Check(
                "fail",
                "machine travel: toolpath has not run",
                "toolpath has not run",
                not_run="toolpath",
            )
        ]
    outside = int(stats.get("outside_count", 0))
    clipped = int(stats.get("clipped_count", 0))
    total = int(stats.get("input_count", 0))
    checks = []
    if outside or clipped:
        checks.append(
            _Check(
                "fail",
                f"machine travel: {outside} of {total} scratches lie outside it (left out) and "
                f"{clipped} were clipped to it",
                f"{outside + clipped} of {total} scratches left out or clipped",
                "Some scratches fall outside the machine's travel: check the machine "
                "profile's [board] offset_mm and [envelope] (the toolpath preview draws the "
                "travel in blue).",
            )
        )
    else:
        checks.append(_Check("ok", f"machine travel: all {total} scratches inside it"))
    seconds = stats.get("estimated_time_s")
    if isinstance(seconds, int | float):
        checks.append(
            _Check(
                "info",
                f"estimated cutting time: <span data-stat='toolpath.time'>"
                f"{duration_text(float(seconds))}</span>",
            )
        )
    return checks


def _gcode_check(job: Path) -> list[_Check]:
    gcode = JobLayout(job).export_file("gcode")
    if gcode.is_file():
        return [_Check("ok", f"G-code written: {_link(job, gcode)}")]
    return [_Check("fail", "G-code: export has not run", "no G-code yet", not_run="export")]


#: How the verdict and the Stream section name a journal session not the latest run's.
_SESSION = {
    "latest": "",
    "earlier": "an earlier run's session: ",
    "unsure": "the journal's last session (perhaps an earlier run's): ",
}


def _stream_check(state: _Stream, outcome: _Stopped | None = None) -> list[_Check]:
    """The verdict's stream lines: the latest run's failure (``outcome``), then the journal's."""
    checks = []
    if outcome is not None:
        checks.append(
            _Check(
                "fail",
                # said after its topic, as the other lines are, so that "✘ no" reads right
                f"stream: the last one {html.escape(outcome.said)}"
                + (f": {html.escape(outcome.why)}" if outcome.why else ""),
                f"the stream {outcome.said}",
                "Deal with what stopped the stream: its line above says what happened "
                "and what to do.",
            )
        )
    if state.kind == "none":
        return [*checks, _Check("info", f"not streamed{state.note}")]
    if outcome is None and state.kind == "real" and not state.finished:
        # the manifest does not say it stopped (a stream by hand, or a stage that ended)
        stopped = f"the cut stopped after {state.done} of {state.total} lines"
        # its steps are resume's (:func:`_next_steps`), so no fix
        checks.append(_Check("fail", f"stream: {stopped} (its journal records no end)", stopped))
    end = "to the end" if state.finished else f"{state.done} of {state.total} lines, unfinished"
    text = {
        "emulator": f"streamed to the built-in GRBL emulator ({end}): nothing was cut",
        "real": f"streamed to the machine on {html.escape(state.port or '')} ({end})",
        "unknown": f"streamed ({end}) to a port this report does not know",
    }[state.kind]
    return [*checks, _Check("info", _SESSION[state.session] + text)]


def _cut_head(state: _Stream, outcome: _Stopped | None, cuts: int | None) -> str:
    """The verdict's heading after the job's G-code was streamed to its end ("" if not).

    Only where the latest run's stream did not fail or stop (``outcome`` None, else its
    failure comes first); ``cuts``: the G-code's cutting moves (None: not counted).
    """
    if outcome is not None or not state.finished or state.session != "latest":
        return ""
    scratches = "" if cuts is None else f"{cuts} scratch{'' if cuts == 1 else 'es'}, "
    if state.kind == "real":
        return (
            f"The board is cut: {scratches}all {state.total} G-code lines streamed to the "
            f"machine on {state.port}"
        )
    if state.kind == "unknown":
        return (
            f"Streamed to the end ({scratches}{state.total} G-code lines) to a port this "
            "report does not know: the board is cut if that port is your machine"
        )
    return ""  # the emulator: nothing was cut, the board is still to cut


def _verdict(checks: list[_Check], cut: str = "") -> str:
    """The verdict box: its heading, then every check's line.

    ``cut``: :func:`_cut_head`'s heading where the G-code was streamed to its end; a
    check that fails is named after it.
    """
    fails = [c for c in checks if c.status == "fail"]
    warns = [c for c in checks if c.status == "warn"]
    reasons = html.escape("; ".join(c.reason for c in fails))
    read = f" (read the {len(warns)} warning{'s' if len(warns) > 1 else ''} below)" if warns else ""
    if cut:
        failing = f"{len(fails)} checks below fail" if len(fails) > 1 else "1 check below fails"
        head = html.escape(cut) + (f", though {failing}: {reasons}" if fails else read)
        cls, verdict = "notready" if fails else "ready", "cut"
    elif fails:
        head = "Not ready: " + reasons
        cls, verdict = "notready", "not-ready"
    else:
        head = "Ready to cut" + read
        cls, verdict = "ready", "ready"
    lines = "".join(
        f"<li data-check='{c.status}'><span class='{_CSS[c.status]}'>{_MARK[c.status]}</span> "
        f"{c.html}</li>"
        for c in checks
    )
    return (
        f"<div class='verdict {cls}' data-verdict='{verdict}'><h2>{head}</h2><ul>{lines}</ul></div>"
    )


# --- sections ---------------------------------------------------------------------


def _views_section(
    job: Path,
    names: list[str],
    metrics: dict[str, Any] | None,
    min_rho: float | None,
    maps: Any,
    stopped: Mapping[str, str],
) -> str:
    """Each view's pictures, then the measurements; ``maps`` is feasibility.json's data.

    ``stopped``: the stages that failed or stopped, as :func:`_absent` takes them.
    """
    layout = JobLayout(job)
    if not names:
        return _absent("design", stopped)
    maps_text = (
        str(maps.get("maps", "")).split(": ", 1)[-1]
        if isinstance(maps, dict)
        else "where the tool reaches this view"
    )
    verified = (metrics or {}).get("views")
    rows = []
    for name in names:
        n = html.escape(name)
        entry = verified.get(name) if isinstance(verified, dict) else None
        share = entry.get("glint_share") if isinstance(entry, dict) else None
        noisy = diff_noise_advice(entry, "[verify] spp =") if isinstance(entry, dict) else ""
        noise_line = f"<br><span class='warn' data-noise='{n}'>{html.escape(noisy)}</span>"
        glint = (
            "; a purple outline marks where the bare board glints: no scratch shows the "
            "image there, and its light sets the exposure, so the rest reads darker"
            if isinstance(share, int | float) and share > 0
            else ""
        )
        shown = (
            (layout.design.target_png(name), "target", f"target: what {n} should look like"),
            (
                layout.optimize_renders / f"{name}.png",
                "optimized render",
                "optimizer's prediction: the optimized scratches under the design light "
                "(its fast model)",
            ),
            (
                layout.verify_dir / f"{name}.png",
                "verify render",
                "independent check: Mitsuba 3 render of the optimized scratches from here",
            ),
            (
                layout.verify_diff_png(name),
                "difference map",
                "difference map: where the verified board is brighter (orange) or darker "
                "(blue) than the target, measured as the PSNR below measures it; the "
                f"colour scale is the same for every view and run{glint}"
                + (noise_line if noisy else ""),
            ),
            (
                layout.design.feasibility_png(name),
                "feasibility",
                f"feasibility map: {html.escape(maps_text)}",
            ),
        )
        # the maps with a key at their own size (the key's text at full size)
        wide = (layout.verify_diff_png(name), layout.design.feasibility_png(name))
        rows.append(
            (name, [(png, f"{name} {label}", text, png in wide) for png, label, text in shown])
        )
    # every view's boxes as wide as the widest picture of any
    pictures = [(png, wide) for _, row in rows for png, _, _, wide in row if png.is_file()]
    width = max((_shown_width(png, wide) for png, wide in pictures), default=PICTURE_PX)
    parts = [
        f"<h3>view {html.escape(name)}</h3><div class='row views'>"
        + "".join(
            _figure(png, alt, caption, wide=wide, width=width)
            for png, alt, caption, wide in row
            if png.is_file()
        )
        + "</div>"
        for name, row in rows
    ]
    return "\n".join(parts) + _metrics_table(names, metrics, min_rho, stopped)


def _metrics_table(
    names: list[str],
    metrics: dict[str, Any] | None,
    min_rho: float | None,
    stopped: Mapping[str, str],
) -> str:
    if not metrics or not isinstance(metrics.get("views"), dict):
        return _absent("verify", stopped, ": no measurements")
    views = metrics["views"]
    names = [k for k in names if k in views] or list(views)
    head = (
        "<tr><th>view</th><th>looks like its target: rho (1 = perfect)</th>"
        "<th>PSNR (dB, higher is better)</th>"
        "<th>Mitsuba vs optimizer's render: difference (rel. L2)</th>"
        "<th>samples per pixel</th><th>render time</th></tr>"
    )
    rows = []
    for k in names:
        v = views[k]
        cells = []
        for key, shown in (
            ("rho", lambda x: f"{x:.3f}"),
            ("psnr", lambda x: f"{x:.2f}"),
            ("rel_l2", lambda x: f"{100 * x:.2f} %"),
            ("spp", lambda x: f"{x:.0f}"),
            ("seconds", lambda x: f"{x:.1f} s"),
        ):
            value = v.get(key)
            if value is None:
                cells.append("<td>–</td>")
                continue
            mark = ""
            noise = v.get("noise")
            if key == "rel_l2" and isinstance(noise, int | float) and noise >= value / 2:
                mark = (  # most of the difference is the Mitsuba render's own noise
                    f"<span class='muted'> (its sampling noise alone: {100 * noise:.2f} %)</span>"
                )
            if key == "rho" and gate_applies(min_rho):
                good = value >= min_rho
                mark = (
                    f" <span class='{'ok' if good else 'bad'}'>{'✔ ok' if good else '✘ low'}</span>"
                )
            cells.append(
                f'<td data-metric="{html.escape(k)}.{key}" data-value="{value}">'
                f"{shown(value)}{mark}</td>"
            )
        rows.append(f"<tr><th scope='row'>{html.escape(k)}</th>{''.join(cells)}</tr>")
    matrix_rows = []
    for k in names:
        cells = []
        for j in names:
            x = views[k].get("crosstalk", {}).get(j)
            if j == k or x is None:
                cells.append("<td>–</td>")
            else:
                cells.append(
                    f'<td data-metric="{html.escape(k)}.crosstalk.{html.escape(j)}" '
                    f'data-value="{x}">{_fmt(x)}</td>'
                )
        matrix_rows.append(f"<tr><th scope='row'>{html.escape(k)}</th>{''.join(cells)}</tr>")
    header = "".join(f"<th>{html.escape(j)}</th>" for j in names)
    gate = (
        f"rho is marked ok at or above <span data-stat='min_rho'>{min_rho:g}</span> "
        "([verify] min_rho), low below it."
        if gate_applies(min_rho)
        else "No [verify] min_rho is set: rho is not judged."
        if min_rho is None
        else f"[verify] min_rho is <span data-stat='min_rho'>{min_rho:g}</span>, no gate: "
        "rho is not judged."
    )
    table = (
        "<h3>Measured by the independent renderer (verify)</h3>"
        f"<table>{head}{''.join(rows)}</table><p>{gate}</p>"
    )
    if len(names) > 1:
        table += (
            "<h3>Crosstalk: how much of picture j (column) shows in view k (row)</h3>"
            "<p>Beyond what the two pictures already share; 0 = none, 1 = fully. No limit is "
            "configured for it.</p>"
            f"<table><tr><th></th>{header}</tr>{''.join(matrix_rows)}</table>"
        )
    return table


def _optimize_section(job: Path, names: list[str], stopped: Mapping[str, str]) -> str:
    layout = JobLayout(job)
    out = []
    if layout.loss_png.is_file():
        out.append(
            _figure(
                layout.loss_png,
                "loss curve",
                "optimize's loss per iteration: how far the renders are from the targets "
                "(lower is better)",
                wide=True,
            )
        )
    summary = _read_json(layout.optimize_summary)
    intro = ""
    if isinstance(summary, dict) and "iterations" in summary:
        elapsed = summary.get("elapsed_s")
        took = f" in {duration_text(float(elapsed))}" if isinstance(elapsed, int | float) else ""
        count = summary.get("scratches")
        intro = (
            f"<p>{_fmt(summary['iterations'])} iterations{took}"
            + (f", {_fmt(count)} scratches" if count is not None else "")
            + (
                ", run to the end"
                if summary.get("stopped") == "done"
                else f" (stopped: {html.escape(str(summary.get('stopped')))})"
            )
            + ".</p>"
        ) + _glint_left_out(summary.get("glint_left_out"), names)
    log = layout.optimize_log
    if log.is_file():
        with log.open(encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
        if rows:
            out.append(_last_iteration(rows[-1], names))
    if not out and not intro:
        return _absent("optimize", stopped)
    return f"{intro}<div class='row'>{''.join(out)}</div>"


def _glint_left_out(left_out: Any, names: list[str]) -> str:
    """A paragraph on the views whose glint optimize left out (summary.json's record)."""
    if not isinstance(left_out, dict):
        return ""
    shares = {str(k): float(v) for k, v in left_out.items() if isinstance(v, int | float) and v > 0}
    order = [n for n in names if n in shares] + sorted(set(shares) - set(names))
    if not order:
        return ""
    listed = ", ".join(f"{html.escape(n)} ({100 * shares[n]:.1f}% of the board)" for n in order)
    return (
        f"<p data-glint-left-out='{len(order)}'>The bare board glints into "
        f"{'views' if len(order) > 1 else 'view'} {listed}: no scratch can show the image "
        "there, so optimize left those pixels out of its image error (its loss). The rho and "
        "PSNR below and verify's count every pixel, the glint too.</p>"
    )


def _last_iteration(last: dict[str, str], names: list[str]) -> str:
    """The log's last row as one line per view, in words (not log.csv's column names)."""

    def cell(key: str, digits: int) -> str:
        try:
            value = float(last.get(key) or "nan")
        except ValueError:
            value = math.nan
        if math.isnan(value):
            return "<td>–</td>"
        return f"<td>{value:.{digits}f}</td>" if math.isfinite(value) else "<td>∞</td>"

    others = len(names) > 1
    head = (
        "<tr><th>view</th><th>looks like its target: rho (1 = perfect)</th>"
        "<th>PSNR (dB)</th>"
        + ("<th>crosstalk (worst other picture)</th>" if others else "")
        + "</tr>"
    )
    rows = []
    for k in names:
        xs = []
        for j in names:
            try:
                xs.append(float(last.get(f"x_{k}_{j}") or "nan"))
            except ValueError:
                continue
        finite = [x for x in xs if not math.isnan(x)]
        cross = f"<td>{max(finite):.3f}</td>" if finite else "<td>–</td>"
        rows.append(
            f"<tr><th scope='row'>{html.escape(k)}</th>{cell(f'rho_{k}', 3)}"
            f"{cell(f'psnr_{k}', 2)}{cross if others else ''}</tr>"
        )
    iteration = html.escape(last.get("iteration", "?"))
    return (
        f"<figure><table>{head}{''.join(rows)}</table><figcaption>the optimizer's own "
        f"measure of its fast model at its last logged iteration ({iteration}); loss "
        f"{html.escape(last.get('loss', '?'))}</figcaption></figure>"
    )


def _walk_section(job: Path, metrics: dict[str, Any] | None, stopped: Mapping[str, str]) -> str:
    gif = JobLayout(job).verify_dir / "sweep.gif"
    if not gif.is_file():
        if metrics is None:
            return _absent("verify", stopped, ": no walk-past animation")
        return "<p class='muted'>no walk-past animation ([verify] sweep = 0).</p>"
    sweep = (metrics or {}).get("sweep") if isinstance(metrics, dict) else None
    detail = ""
    if isinstance(sweep, dict):
        cameras = sweep.get("cameras") or []
        try:
            first = polar_from_position(tuple(cameras[0]["position_mm"]))[0]
            last = polar_from_position(tuple(cameras[-1]["position_mm"]))[0]
            detail = f", from {side(first)} to {side(last)} of the board's front"
        except (IndexError, KeyError, TypeError, ValueError):
            detail = ""
        if isinstance(sweep.get("nearest_frame"), dict) and sweep["nearest_frame"]:
            detail += ", passing the place of each view"
    caption = f"the board under the design light as a viewer walking past it sees it{detail}"
    return f"<div class='row'>{_figure(gif, 'walk past the board', caption, wide=True)}</div>"


def _sky_section(job: Path, names: list[str], metrics: dict[str, Any] | None) -> str:
    folder = JobLayout(job).verify_dir / "sky"
    pngs = {p.stem: p for p in folder.glob("*.png")}
    if not pngs:
        return ""
    order = [n for n in names if n in pngs] + sorted(set(pngs) - set(names))
    sky = (metrics or {}).get("sky") if isinstance(metrics, dict) else None
    sky_views = sky.get("views", {}) if isinstance(sky, dict) else {}
    figures = []
    for name in order:
        rho = sky_views.get(name, {}).get("rho")
        said = f"; looks like its target: rho {rho:.3f}" if isinstance(rho, float) else ""
        figures.append(
            _figure(
                pngs[name],
                f"{name} under sun and sky",
                f"view {html.escape(name)} outdoors, under sun and sky instead of the "
                f"design light{said}",
            )
        )
    return (
        "<h2>Under sun and sky</h2><p>The same board in daylight (verify's sky option): "
        "a broad sky washes the pictures out; a low sun picks them out.</p>"
        f"<div class='row'>{''.join(figures)}</div>"
    )


_TOOLPATH_ROWS = (
    ("count", "scratches to cut", lambda v: f"{v:.0f}"),
    ("input_count", "scratches in the design", lambda v: f"{v:.0f}"),
    ("outside_count", "left out: outside the machine's travel", lambda v: f"{v:.0f}"),
    ("clipped_count", "clipped to the machine's travel", lambda v: f"{v:.0f}"),
    ("short_count", "left out: too short for the tool", lambda v: f"{v:.0f}"),
    ("merged_count", "left out: duplicates", lambda v: f"{v:.0f}"),
    ("cut_length_mm", "cut length", lambda v: f"{v / 1000:.2f} m"),
    ("travel_length_mm", "travel between cuts", lambda v: f"{v / 1000:.2f} m"),
    ("travel_input_order_mm", "travel in the design's order", lambda v: f"{v / 1000:.2f} m"),
    ("estimated_time_s", "estimated cutting time", lambda v: duration_text(v)),
)


def _toolpath_section(job: Path, data: Any, stopped: Mapping[str, str]) -> str:
    """The preview and the figures of ``toolpath.json`` (``data``, None if unreadable)."""
    layout = JobLayout(job)
    parts = []
    if layout.toolpath_preview.is_file():
        parts.append(
            _figure(
                layout.toolpath_preview,
                "toolpath preview",
                "toolpath seen from the front: the board's outline, the cuts, the travel "
                "moves between them, the limits of the machine's travel and the start point",
                full=True,  # its title and legend are small beside 1500 px of strokes
            )
        )
    stats = (data or {}).get("statistics") if isinstance(data, dict) else None
    if isinstance(stats, dict):
        cells = "".join(
            f"<tr><th scope='row'>{label}</th><td data-stat='toolpath.{key}' "
            f"data-value='{stats[key]}'>{shown(float(stats[key]))}</td></tr>"
            for key, label, shown in _TOOLPATH_ROWS
            if isinstance(stats.get(key), int | float)
        )
        parts.append(
            f"<figure><table>{cells}</table><figcaption>the toolpath's figures (toolpath/toolpath.json)</figcaption></figure>"
        )
    return f"<div class='row'>{''.join(parts)}</div>" if parts else _absent("toolpath", stopped)


def gcode_statistics(path: Path, profile: MachineProfile | None = None) -> dict[str, Any]:
    """A G-code file's size, and its lines, moves and extent as the sender reads them.

    ``sent``: the lines the sender sends (its count, which ``stream`` and the journal
    give: comments and blank lines are not sent), or why it refuses the file. Where it
    reads the file, the X, Y and Z ranges its moves reach (work mm, arcs swept: a word
    the sender reads, ``G0X1Y2`` or ``G20`` inches too) and :func:`move_counts` (rapid,
    feed and cutting moves) follow, its strokes told as ``stream`` tells them for
    ``profile`` (the toolpath's machine).
    """
    from scratchfab.machine.sender_checks import job_extent
    from scratchfab.machine.stream_job import load_program_for

    # errors="replace": a Latin-1 comment is counted; the sender says why it refuses it
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    extent: dict[str, str] = {}
    moves: dict[str, int] = {}
    try:
        program = load_program_for(path, profile)
        sent: int | str = len(program.blocks)
        lo, hi = job_extent(program)
        extent = {
            f"{axis} range": f"{a:g} .. {b:g} mm"
            for axis, a, b in zip("XYZ", lo, hi, strict=True)
            if a <= b
        }
        moves = move_counts(program)
    except ConfigError as exc:
        # the file's name alone: the page names no absolute path (the folder may move)
        sent = f"none: stream refuses the file ({str(exc).replace(str(path), path.name)})"
    return {
        "lines": len(lines),
        "sent": sent,
        "bytes": path.stat().st_size,
        "longest_line": max((len(line) for line in lines), default=0),
        **extent,
        **moves,
    }


#: The package's folder: the G-code record's key hashes every module in it.
_PACKAGE = Path(__file__).resolve().parent.parent


def _source_digest(package: Path) -> str:
    """SHA-256 of every module of ``package`` (its path and bytes), in a stable order.

    Raises:
        OSError: A module cannot be read, or there is none (a frozen build).
    """
    modules = sorted(package.rglob("*.py"), key=lambda p: p.relative_to(package).as_posix())
    if not modules:
        raise FileNotFoundError(f"no Python source in {package}")
    digest = hashlib.sha256()
    for module in modules:
        digest.update(module.relative_to(package).as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(module.read_bytes()).digest())
    return digest.hexdigest()


def _statistics_key(gcode: Path, profile: MachineProfile | None) -> dict[str, str]:
    """What :func:`gcode_statistics` of ``gcode`` for ``profile`` depends on, hashed.

    The file's bytes and name, the profile (its repr: every field), and the code that
    reads the file (every module of the package, about 8 ms: the sender's parser reads
    through the profile's words, the unit codes, the file reader and the tool's commands):
    a changed reader counts again rather than show an earlier version's figures.
    """
    from scratchfab.fileio import file_sha256

    return {
        "gcode": file_sha256(gcode),
        "name": gcode.name,
        "profile": hashlib.sha256(repr(profile).encode()).hexdigest(),
        "readers": _source_digest(_PACKAGE),
    }


#: The ``id`` of report.html's record of its G-code figures (:func:`cached_gcode_statistics`).
_STATS_RECORD = "gcode-statistics"
#: How much of report.html's head the record is looked for in (it lies about 2 KB in).
_RECORD_WITHIN = 64 * 1024


def _kept_statistics(page: Path) -> Any:
    """The record an earlier report.html kept of its G-code figures (None without one).

    Read only where the page is a regular file (a FIFO there would wait for a writer),
    and only its first :data:`_RECORD_WITHIN` bytes.
    """
    try:  # not blocking: opening a FIFO for reading waits for a writer otherwise
        fd = os.open(page, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except (OSError, ValueError):
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        with open(fd, "rb", closefd=False) as handle:
            head = handle.read(_RECORD_WITHIN)
    except OSError:
        return None
    finally:
        os.close(fd)
    opening = f"<script type='application/json' id='{_STATS_RECORD}'>".encode()
    found = re.search(re.escape(opening) + rb"(.*?)</script>", head)
    try:
        return decode_json(found.group(1).decode("utf-8")) if found else None
    except ValueError:
        return None


def cached_gcode_statistics(
    job: Path, profile: MachineProfile | None
) -> tuple[dict[str, Any], str]:
    """:func:`gcode_statistics` of the job's G-code, and the page's record of them.

    Reading a big file as the sender does takes seconds (about 5 s at 96k lines), at every
    report. The page keeps its figures in a record with what they depend on
    (:func:`_statistics_key`: the G-code's SHA-256, never its time), which the next report
    reads back where every part of the key is the same: never stale, and no file beside
    the page. Figures counted while the file changed get no record ("").
    """
    layout = JobLayout(job)
    gcode = layout.export_file("gcode")
    try:
        key = _statistics_key(gcode, profile)
    except OSError:  # a reader's source not at hand (a frozen build): read, keep nothing
        return gcode_statistics(gcode, profile), ""
    kept = _kept_statistics(layout.report_html)
    if isinstance(kept, dict) and kept.get("key") == key and isinstance(kept.get("stats"), dict):
        stats = kept["stats"]
    else:
        stats = gcode_statistics(gcode, profile)
        if _statistics_key(gcode, profile) != key:  # changed while it was read
            return stats, ""
    # "<" escaped: a quoted G-code line cannot end the script element
    data = json.dumps({"key": key, "stats": stats}).replace("<", "\\u003c")
    return stats, f"<script type='application/json' id='{_STATS_RECORD}'>{data}</script>"


def move_counts(program: Program) -> dict[str, int]:
    """A program's rapid moves (``G0``), feed moves (``G1``) and cutting moves (``cuts``).

    Moves in the modal motion mode (a line without its G word counts too); G28/G30 (to a
    stored position) are neither. A cutting move goes in XY with the tool down: after the
    block of a stroke that puts the tool down and before the one that lifts it (the
    sender's strokes, :attr:`Program.strokes`: Z below the cutting height, or a servo's
    M3). A plunge and a lift are feed or rapid moves, not cuts; so is travel at a feed
    (a servo plotter's ``[feeds] travel_mm_min``). No ``cuts`` where the sender cannot
    tell the tool's state (no Z below a travel height, no M3 without Z).
    """
    from scratchfab.machine.sender_program import block_words

    blocks = program.blocks
    counts = {"G0": 0, "G1": 0}
    for b in blocks:
        stored = any(w == ("G", 28.0) or w == ("G", 30.0) for w in block_words(b.text))
        if b.motion and not stored and b.modal.motion in ("G0", "G1"):
            counts[b.modal.motion] += 1
    if program.z_threshold is None and not program.pen_mode:
        return counts  # the sender cannot tell its strokes: no count of cuts
    counts["cuts"] = 0
    for first, last in program.strokes:
        for i in range(first + 1, last):
            now, before = blocks[i].modal, blocks[i - 1].modal
            moved = now.motion in ("G2", "G3") or None in (now.x, now.y)
            if blocks[i].motion and (moved or (now.x, now.y) != (before.x, before.y)):
                counts["cuts"] += 1
    return counts


_GCODE_LABELS = {
    "lines": "lines in the file",
    "sent": "lines sent to the machine (as <code>stream</code> counts them: comments and "
    "blank lines are not sent)",
    "bytes": "size (bytes)",
    "longest_line": "longest line (characters)",
    "G0": "rapid moves (G0)",
    "G1": "feed moves (G1: the cuts, and the plunges or any travel at a feed)",
    "cuts": "cutting moves (in X and Y with the tool down, as <code>stream</code> finds the "
    "strokes)",
}


def _files_section(job: Path, stopped: Mapping[str, str], stats: dict[str, Any] | None) -> str:
    """The job's exported files, then ``stats`` (:func:`gcode_statistics` of its G-code)."""
    layout = JobLayout(job)
    what = {
        "gcode": "for the machine",
        "svg": "drawing, for a look or a laser",
        "dxf": "drawing, for CAD",
    }
    items = [
        f"<li>{_link(job, f)} ({f.stat().st_size} bytes"
        + (f", {what[f.suffix[1:]]}" if f.suffix[1:] in what else "")
        + ")</li>"
        for f in layout.export_files()
    ]
    for path, text in (
        (layout.optimized_scratches, "the optimized scratches (one per row, mm)"),
        (layout.verify_metrics, "every measurement of verify"),
    ):
        if path.is_file():
            items.append(f"<li>{_link(job, path)}: {text}</li>")
    if not items:
        return _absent("export", stopped)
    table = ""
    if stats is not None:
        table = (
            "<table>"
            + "".join(
                f"<tr><th scope='row'>{_GCODE_LABELS.get(k, html.escape(k))}</th>"
                f"<td data-stat='gcode.{k}'>{html.escape(str(v))}</td></tr>"
                for k, v in stats.items()
            )
            + "</table>"
        )
    return f"<ul>{''.join(items)}</ul>{table}"


def _stream_outcome(outcome: _Stopped | None) -> str:
    """The Stream section's first paragraph: how the latest run's stream ended, if badly."""
    if outcome is None:
        return ""
    why = f": {html.escape(outcome.why)}" if outcome.why else ""
    return (
        f"<p class='bad' data-stream-outcome>The last stream {html.escape(outcome.said)}{why}.</p>"
    )


def _session(
    start: Mapping[str, Any], outcome: _Stopped | None
) -> Literal["latest", "earlier", "unsure"]:
    """Whether the journal's last session (its ``start`` event) is the latest run's.

    Without a failed or stopped latest run (``outcome``) it is. Else the session is that
    run's when it began no earlier than the run did (both times to the second, local).
    """
    if outcome is None:
        return "latest"
    began = start.get("time")
    if outcome.started is None or not isinstance(began, str):
        return "unsure"
    return "latest" if began >= outcome.started else "earlier"


def _stream_state(
    job: Path, port: str | None, outcome: _Stopped | None = None
) -> tuple[_Stream, str]:
    """The stream's state and the Stream section's paragraphs.

    ``outcome``: the manifest's word where the latest run's stream failed or stopped;
    said first, and the journal's session is told as an earlier run's where it is one.
    """
    state, text = _journal_state(job, port, outcome)
    return state, _stream_outcome(outcome) + text


def _journal_state(job: Path, port: str | None, outcome: _Stopped | None) -> tuple[_Stream, str]:
    """The journal's state and its paragraph (see :func:`_stream_state`)."""
    from scratchfab.fileio import file_sha256
    from scratchfab.machine.sender_journal import (
        default_journal_path,
        done_blocks,
        interrupted,
        last_start,
        read_journal,
    )
    from scratchfab.pipeline.runner import is_emulator

    gcode = JobLayout(job).export_file("gcode")
    journal = default_journal_path(gcode)
    if not journal.is_file() or not gcode.is_file():
        said = "the journal records no stream" if outcome is not None else "not streamed"
        return _Stream("none"), f"<p class='muted'>{said}.</p>"
    try:
        events = read_journal(journal)
        start = last_start(events)
        if not start:
            return _Stream("none"), "<p class='muted'>not streamed (the journal is empty).</p>"
        sha256 = str(start.get("sha256"))
        done = len(done_blocks(events, sha256, journal, recut_unclosed=False))
    except ConfigError as exc:
        return _Stream("none", note=" (the journal is damaged)"), (
            f"<p class='bad'>{html.escape(str(exc))}</p>"
        )
    if sha256 != file_sha256(gcode):
        note = " (the journal's last stream was of an earlier G-code)"
        return _Stream("none", note=note), f"<p>Not streamed{note}.</p>"
    total = int(start.get("blocks") or 0)
    finished = not interrupted(events, sha256)
    streamed_to = start.get("port")
    if isinstance(streamed_to, str):  # journals before this field: the pipeline's port
        port = streamed_to
    kind: Literal["emulator", "real", "unknown"] = (
        "unknown" if port is None else "emulator" if is_emulator(port) else "real"
    )
    session = _session(start, outcome)
    state = _Stream(kind, finished, done, total, port, session=session)
    progress = "finished" if finished else "unfinished (the next run resumes it)"
    counted = (
        f"<span data-stat='stream.acknowledged'>{done}</span> of "
        f"<span data-stat='stream.lines'>{total}</span> G-code lines acknowledged"
    )
    rel = _link(job, JobLayout(job).journal)
    if kind == "emulator":
        text = (
            f"<p data-stream='emulator'><b>Streamed to the built-in GRBL emulator: nothing "
            f"was cut.</b> {counted} by the emulator since the last fresh start; {progress} "
            f"({rel}). The emulator only checks that the machine would take the file.</p>"
        )
    elif kind == "real":
        text = (
            f"<p data-stream='real'>Streamed to the machine on {_code(port or '')}: {counted} "
            f"by the controller since the last fresh start; {progress} ({rel}).</p>"
        )
    else:
        text = (
            f"<p data-stream='unknown'>{counted} since the last fresh start; {progress} "
            f"({rel}). The pipeline names no [stream] port, so this report cannot tell a "
            "machine from the emulator.</p>"
        )
    if session != "latest":
        began = html.escape(str(start.get("time") or "at a time it does not record"))
        said = html.escape(outcome.said if outcome else "")
        head = (
            f"The journal's last session, started {began}, is an earlier run's, not the one "
            f"that {said}:"
            if session == "earlier"
            else f"The journal's last session, started {began}, may be an earlier run's than "
            f"the one that {said} (the manifest does not say when that one began):"
        )
        text = f"<p data-session='{session}'>{head}</p>{text}"
    return state, text


def _copied_title(title: str, pipeline_file: Path | None) -> str:
    """A muted line where the title is a bundled pipeline's name, kept in a copy of it.

    "" otherwise. The copy's board is likely another than the one its name describes.
    """
    import tomllib

    from scratchfab.bundled import bundled_dir

    if pipeline_file is None or bundled_name("pipelines", pipeline_file) is not None:
        return ""
    for bundled in sorted(bundled_dir("pipelines").glob("*.toml")):
        try:
            name = tomllib.loads(bundled.read_text(encoding="utf-8")).get("pipeline", {})
        except (OSError, tomllib.TOMLDecodeError):
            continue
        if isinstance(name, dict) and name.get("name") == title:
            return (
                "<p class='muted' data-title-note>This title is <code>[pipeline] name</code> "
                f"in {_code(pipeline_file.name)}, as the bundled {html.escape(bundled.stem)} "
                "pipeline names its board: give yours its own name there.</p>"
            )
    return ""


#: Which way a machine direction lies for a person at a desktop engraver's front, where
#: machine +Y runs away from them (the usual set-up; a profile does not say).
_TOWARD = {"+Y": "away from you", "-Y": "toward you", "+X": "to your right", "-X": "to your left"}
#: A corner of the board as it lies on the machine (``[board] origin``): its sides, then
#: how it reads from the machine's front where +Y runs away.
_MACHINE_CORNER = {
    "lower-left": ("-X", "-Y", "front left"),
    "lower-right": ("+X", "-Y", "front right"),
    "upper-left": ("-X", "+Y", "back left"),
    "upper-right": ("+X", "+Y", "back right"),
}
#: The picture's corners (its top edge up, the design's +y) in the order of
#: :meth:`~scratchfab.machine.profile.MachineProfile.board_outline`.
_PICTURE_CORNERS = ("bottom-left", "bottom-right", "top-right", "top-left")


def _toward(axis: str) -> str:
    """Where machine ``axis`` ("+Y", "-X"...) lies, said so that the user can check it."""
    return (
        f"the way the tool moves over the bed when you jog {axis}: {_TOWARD[axis]} on most "
        "desktop engravers"
    )


def _picture_corner(profile: MachineProfile, board_mm: tuple[float, float]) -> str:
    """The picture's corner that the board's ``[board] origin`` corner is, once turned."""
    placed = profile.board_outline(board_mm)
    at = np.linalg.norm(placed - np.asarray(profile.board.offset_mm), axis=1)
    return _PICTURE_CORNERS[int(np.argmin(at))]


def _origin_words(profile: MachineProfile, board_mm: tuple[float, float]) -> tuple[str, str]:
    """The board point ``[board] offset_mm`` places: (what it is, how to jog to it again).

    A corner is named as it lies on the machine (its sides' axes, and where that is from
    the machine's front), and as the picture's corner it is, whatever the rotation.
    """
    if profile.board.origin == "center":
        return "centre", "the board's centre"
    x, y, seen = _MACHINE_CORNER[profile.board.origin]
    turned = profile.board.rotation_deg
    picture = _picture_corner(profile, board_mm)
    what = (
        f"corner at machine {x} {y} ({seen} where machine +Y runs away from you, as on most "
        "desktop engravers; the picture's "
        f"<span data-stat='setup.picture_corner'>{picture}</span> corner"
        + (f", the board being turned {turned}°" if turned else "")
        + ")"
    )
    return what, f"the board's {x} {y} corner"


def _planned_profile(toolpath: Any) -> MachineProfile | None:
    """The machine profile ``toolpath.json`` (read) records; None without a usable one."""
    from scratchfab.machine.profile import profile_from_mapping

    if not isinstance(toolpath, dict):
        return None
    try:
        return profile_from_mapping(toolpath.get("machine"), "toolpath.json: machine")
    except ConfigError:  # no toolpath yet, or a damaged one
        return None


def _setup_step(job: Path) -> str:
    """How to set the machine up, for the profile the toolpath was planned with.

    README step 5, the board's placement and the tool's height, the zeroing the profile's
    ``[envelope] coordinates`` calls for (none on the board, or the work zero in the work
    system in use), and which way the board's top edge faces (as the G-code's header
    says), to mark before unclamping.
    """
    text = (
        "Set the machine up as README step 5 (<b>Cut.</b>) says for your profile: the G-code "
        "moves in the profile's own coordinates"
    )

    from scratchfab.toolpath import Toolpath

    try:
        toolpath = Toolpath.load(JobLayout(job).toolpath_json)
    except ConfigError:  # no toolpath yet, or a damaged one: the pointer alone
        return text + "."
    from scratchfab.machine.sender import work_zero_command

    profile = toolpath.profile
    x, y = profile.origin_xy_text()  # the numbers of the command to send (no 1e-05)
    corner, jog_to = _origin_words(profile, toolpath.board_mm)
    servo = profile.tool_control.mode == "servo"
    tool = (
        f"the tool lowered by its on command ({_code(profile.tool_control.command('on'))})"
        if servo
        else f"the tool cutting at Z <span data-stat='setup.z'>{profile.z.engrave_mm:g}</span> mm "
        f"and travelling at Z <span data-stat='setup.safe'>{profile.z.safe_mm:g}</span> mm "
        "(every travel, the first one from where the tool stands too: clamps and anything "
        "else on the bed must lie lower)"
    )
    placed = (
        f" ('{html.escape(profile.name)}'): the board's {corner} at X "
        f"<span data-stat='setup.x'>{x}</span> Y <span data-stat='setup.y'>{y}</span>, "
        f"{tool}. "
    )
    top = profile.board_top()
    marked = (
        f" The board's top edge (the picture's top, the design's +y) faces machine "
        f"<span data-stat='setup.top'>{top}</span> ({_toward(top)}): mark it on the board "
        "before you unclamp it, since every place under <i>Where to stand</i> holds with "
        "that edge up."
    )
    # P0: the work system in use, the one the G-code runs in (it selects none)
    if profile.envelope.coordinates == "machine":
        advice = (
            "Make both true on your machine before streaming: these are GRBL's machine "
            "coordinates after homing, with the work offset cleared "
            f"({_code('G10 L2 P0 X0 Y0 Z0')} for the work system in use, {_code('G92.1')}, "
            f"{_code('G49')}; check with {_code('$#')}; the profile's [envelope] "
            "<code>coordinates = &quot;machine&quot;</code>): do not zero the work "
            "coordinates on the board."
        )
        return text + placed + advice + marked
    z_zero = (
        ""
        if servo
        else f" For Z, touch the tool on the board's surface: Z {profile.z.engrave_mm:g} must "
        f"lie a little below that height (e.g. {_code('G10 L20 P0 Z0')} there, with [z] "
        "<code>engrave_mm</code> a little below 0)."
    )
    # where the point is not X0 Y0, a zero there (a habit) moves every cut by the offset
    shift = [
        f"{v.lstrip('-')} mm {'-' if v.startswith('-') else '+'}{axis}"
        for axis, v in (("X", x), ("Y", y))
        if float(v) != 0
    ]
    not_zero = (
        f": {jog_to} is X {x} Y {y} in the G-code, not X0 Y0 (zeroing X and Y there, with "
        f"{_code('G10 L20 P0 X0 Y0')}, would move every cut {' and '.join(shift)} from where the "
        "design puts it)"
        if shift
        else ""
    )
    advice = (
        "These are work coordinates: set them on the board before streaming. Jog the tool "
        f"to {jog_to} and send {_code(work_zero_command(profile)[1])} there{not_zero}. That "
        f"command makes the point X {x} Y {y} in the work system in use, P0, which the "
        f"G-code runs in as it selects none; G10 L20, not {_code('G92')}, whose zero every "
        f"soft reset clears.{z_zero}"
    )
    return text + placed + advice + marked


def _next_steps(job: Path, checks: list[_Check], state: _Stream, pipeline_file: Path | None) -> str:
    """Steps chosen from the job's state: fix, resume, cut, or look at the cut board."""
    bundled = None if pipeline_file is None else bundled_name("pipelines", pipeline_file)
    if bundled is not None:
        pipe = bundled  # `scratchfab run demo` finds it by name anywhere
    elif pipeline_file is not None:
        # Whichever works from the job folder and is shorter to type (no relative path
        # between two Windows drives).
        absolute = str(pipeline_file.resolve())
        try:
            pipe = min(os.path.relpath(pipeline_file, job), absolute, key=len)
        except ValueError:
            pipe = absolute
    else:
        pipe = "PIPELINE.toml"
    run = ["scratchfab", "run", pipe, "--out", "."]
    rerun = _code(command_line(run))
    again = _code(command_line([*run, "--from", "stream"]))
    steps: list[str] = []
    state_kind = "not-streamed"
    mine = state.session == "latest"  # an earlier run's session says nothing of this one
    if mine and state.kind == "real" and not state.finished:
        state_kind = "resume"
        steps += [
            f"The cut stopped after {state.done} of {state.total} lines: leave the board "
            "clamped where it is and do not move the machine's axes by hand.",
            f"Resume: run {rerun} again: it continues from the journal. If the controller "
            "lost power, set <code>recut_unsure = true</code> in [stream] first.",
        ]
    elif mine and state.kind == "real":
        state_kind = "cut"
        steps += [
            "The board is cut. Lift the tool, take the board off, wipe it clean (no "
            "abrasives) and look at it from the places under <i>Where to stand</i>.",
            f"To cut another board with the same G-code: {again}.",
        ]
    fails = [c for c in checks if c.status == "fail"]
    if fails and state_kind == "not-streamed":
        state_kind = "fix"
        seen: list[str] = []
        for c in fails:
            if c.fix and c.fix not in seen:
                seen.append(c.fix)
        steps += seen or ["Run the stages that have not run."]
        steps.append(f"Then run again: {rerun}.")
    elif state_kind == "not-streamed":
        steps += [
            f"{c.fix} Then run again: {rerun}." for c in checks if c.status == "warn" and c.fix
        ]
        if state.kind == "emulator":
            state_kind = "emulator"
            steps.append(
                "The emulator took the file"
                + ("" if state.finished else " only in part (the next run finishes it)")
                + ": that checks the G-code, but nothing was cut yet."
            )
        steps += [
            "Check the toolpath preview: every scratch inside the board, travel moves sensible.",
            _setup_step(job),
            "Dry-run and cut: "
            + _code("scratchfab stream export/board.gcode --port PORT --check")
            + " runs the file through GRBL's check mode "
            "(nothing moves), then asks before it cuts.",
            (
                "Or copy the bundled pipeline "
                f"{_code(str(pipeline_file.resolve()) if pipeline_file else pipe)} to a file of "
                "your own (the comment at its top says what to re-point), set [stream] "
                "<code>port</code> in it to your machine's port and run "
                f"{_code(command_line(['scratchfab', 'run', 'my.toml', '--out', '.']))}"
                if bundled
                else "Or set [stream] <code>port</code> in the pipeline file to your machine's "
                f"port and run {rerun}"
            )
            + ". After a dropped cable, run the same command again "
            "(<code>scratchfab stream</code> needs <code>--resume</code>).",
        ]
    items = "".join(f"<li>{s}</li>" for s in steps)
    port = (  # only where a command names PORT
        "; PORT is your machine's serial port, e.g. /dev/ttyUSB0 on Linux, "
        "/dev/cu.usbserial-1410 on macOS, COM3 on Windows"
        if any("PORT" in s for s in steps)
        else ""
    )
    where = f"(commands from the job folder{port})"
    return f"<ol data-next='{state_kind}'>{items}</ol><p class='muted'>{html.escape(where)}</p>"


def write_report(
    job: Path,
    title: str = "scratchfab job",
    *,
    port: str | None = None,
    min_rho: float | None = None,
    pipeline_file: Path | None = None,
) -> Path:
    """Write ``JOB/report.html`` from what the stages left in the job folder.

    Args:
        job: The job folder.
        title: The page's heading (``[pipeline] name``).
        port: The pipeline's ``[stream] port``: says whether a stream moved a machine
            or the built-in emulator (None: the report cannot tell).
        min_rho: The pipeline's ``[verify] min_rho`` (None: the one verify recorded in
            ``metrics.json``, if any).
        pipeline_file: The pipeline file, for the commands the next steps give.
    """
    layout = JobLayout(job)
    metrics = _read_json(layout.verify_metrics)
    metrics = metrics if isinstance(metrics, dict) else None
    feasibility = _read_json(layout.design.feasibility_json)
    toolpath = _read_json(layout.toolpath_json)
    if min_rho is None:
        min_rho = _recorded_gate(layout.verify_metrics)
    design = _read_design(job)
    names = _view_order(design, metrics, job)
    stopped_stages = _stopped_stages(job)
    outcome = stopped_stages.get("stream")
    state, stream_text = _stream_state(job, port, outcome)
    stages = _stage_checks(stopped_stages)
    stopped = {stage: s.said for stage, s in stopped_stages.items() if stage != "stream"}
    checks = stages + [
        c
        for c in _feasibility_checks(feasibility)
        + _rho_checks(names, metrics, min_rho, _glint_shares(feasibility), feasibility)
        + _crosstalk_check(names, metrics)
        + _toolpath_checks(toolpath)
        + _gcode_check(job)
        + _stream_check(state, outcome)
        if c.not_run not in stopped
    ]
    gcode = layout.export_file("gcode")
    stats_for = _planned_profile(toolpath)
    gcode_stats, record = cached_gcode_statistics(job, stats_for) if gcode.is_file() else (None, "")
    cuts = (gcode_stats or {}).get("cuts")
    body = [
        f"<h1>{html.escape(title)}</h1><p class='muted'>job folder "
        f"{_code(job.resolve().name)}; every path below is relative to it.</p>"
        + _copied_title(title, pipeline_file),
        "<span id='image-check' hidden></span>",
        _verdict(checks, _cut_head(state, outcome, cuts)),
        "<h2>What to do next</h2>",
        _next_steps(job, checks, state, pipeline_file),
        "<h2>Where to stand</h2>",
        _stand_section(design, stopped),
        "<h2>Views</h2>",
        _views_section(job, names, metrics, min_rho, feasibility, stopped),
        "<h2>Optimization</h2>",
        _optimize_section(job, names, stopped),
        "<h2>Walking past the board</h2>",
        _walk_section(job, metrics, stopped),
        _sky_section(job, names, metrics),
        "<h2>Toolpath</h2>",
        _toolpath_section(job, toolpath, stopped),
        "<h2>Files</h2>",
        _files_section(job, stopped, gcode_stats),
        "<h2>Stream</h2>",
        stream_text,
    ]
    page = (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style>"
        f"<script>{_SCRIPT}</script>{record}</head><body>{''.join(body)}</body></html>\n"
    )
    out = JobLayout(job).report_html
    write_text(out, page)
    return out
