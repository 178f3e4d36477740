"""Fuzzing every reader of a user-supplied file.

Each reader gets valid files (the bundled ones, or files made by the writers), mutated at
random (seeded): truncated, bytes flipped, inserted or deleted, control bytes, invalid
UTF-8, a BOM, CRLF or CR line ends, numbers replaced by huge, non-finite, negative or
zero ones, values of the wrong type, lines duplicated or dropped; and the special paths
(a folder, an empty file, a missing one, a symlink loop). A reader passes a case when it
returns something sane or raises a ScratchfabError of one line naming the file; any
other exception, a hang or a sane-looking result holding NaN fails it.

CI runs a reduced loop (a few seconds); ``SCRATCHFAB_FULL=1`` runs thousands of cases.
The minimal input of each finding of the full review is pinned below as a table case.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import io
import json
import math
import os
import random
import re
import signal
import struct
import tomllib
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w
from conftest import FULL
from PIL import Image

import scratchfab.cli
from scratchfab.bundled import bundled_dir
from scratchfab.design.images import load_image
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import load_numpy
from scratchfab.machine.profile import load_profile
from scratchfab.machine.sender_checks import job_extent
from scratchfab.machine.sender_journal import Journal, done_blocks, read_journal
from scratchfab.machine.sender_program import check_tool_up_at_end, load_program
from scratchfab.model.design import load_design
from scratchfab.model.schema import load_toml
from scratchfab.model.scratches import load_scratches
from scratchfab.optimize.checkpoint import load_checkpoint, save_checkpoint
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.manifest import Manifest

ROOT = Path(__file__).resolve().parents[1]
CASES = 2000 if FULL else 60
HANG_S = 20

GCODE = """G21 G90 G17 G94
(fuzz seed: two strokes)
G0 Z2
G0 X1 Y1
G1 Z-0.2 F200
G1 X5 Y1 F600
G0 Z2
G0 X5 Y3
G1 Z-0.2 F200
G1 X1 Y3 F600
G0 Z2
M5
G0 X0 Y0
M2
"""

# ---------------------------------------------------------------------------- mutations

_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:e-?\d+)?")
_WEIRD_NUMBERS = [b"1e308", b"-1e308", b"1e999", b"inf", b"-inf", b"nan", b"-0", b"0", b"-1"]
_WEIRD_NUMBERS += [b"9" * 5000, b"1" * 400, b"1e-320", b"0x10", b"1_000", b".5", b"1e", b"--1"]
_CONTROL = [b"\x00", b"\x01", b"\x18", b"\x1b", b"\x7f", b"\r", b"\x0b", b"\x0c", b"\x1c"]
_CONTROL += [b"\x85", b"\xff", b"\xc3", b"\xed\xa0\x80", b"\xef\xbb\xbf", b"\xe2\x80\xa8"]
_WEIRD_VALUES: list[Any] = [1e308, -1e308, math.inf, -math.inf, math.nan, -0.0, 0, -1, 10**400]
_WEIRD_VALUES += [2**63, 1e-320, "", "x", "\x00", "nan", True, [], [1, 2], {"a": 1}, "a" * 5000]


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """One random damage to ``data`` (or several)."""
    n = len(data)
    at = rng.randrange(n + 1)
    op = rng.randrange(12)
    if op == 0:
        return data[:at]
    if op == 1 and n:
        flipped = bytearray(data)
        flipped[rng.randrange(n)] ^= 1 << rng.randrange(8)
        return bytes(flipped)
    if op == 2:
        return data[:at] + bytes([rng.randrange(256)]) + data[at:]
    if op == 3:
        return data[:at] + data[at + rng.randrange(1, 20) :]
    if op == 4:
        return data[:at] + rng.choice(_CONTROL) + data[at:]
    if op == 5:
        return b"\xef\xbb\xbf" + data
    if op == 6:
        return data.replace(b"\n", rng.choice([b"\r\n", b"\r"]))
    if op == 7:
        numbers = list(_NUMBER.finditer(data))
        if numbers:
            m = rng.choice(numbers)
            return data[: m.start()] + rng.choice(_WEIRD_NUMBERS) + data[m.end() :]
    if op in (8, 9):
        lines = data.split(b"\n")
        k = rng.randrange(len(lines))
        if op == 8:
            lines.insert(k, lines[k])  # a duplicated key, row or event
        else:
            del lines[k]
        return b"\n".join(lines)
    for _ in range(rng.randrange(2, 5)):
        data = mutate_bytes(data, rng)
    return data


def _paths(tree: Any, here: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    if here:
        yield here
    items = (
        tree.items()
        if isinstance(tree, dict)
        else enumerate(tree)
        if isinstance(tree, list)
        else ()
    )
    for key, value in items:
        yield from _paths(value, (*here, key))


def mutate_tree(tree: Any, rng: random.Random) -> Any:
    """A copy of a TOML/JSON tree with one value replaced by a weird one, or removed."""
    tree = copy.deepcopy(tree)
    paths = list(_paths(tree))
    if not paths:
        return tree
    path = rng.choice(paths)
    parent = tree
    for key in path[:-1]:
        parent = parent[key]
    old = parent[path[-1]]
    if rng.random() < 0.15:
        del parent[path[-1]]
    elif isinstance(old, int | float) and not isinstance(old, bool) and rng.random() < 0.5:
        parent[path[-1]] = rng.choice([0, -old, old * 1e6, -abs(old) - 1, float(old) * 1e300])
    else:
        parent[path[-1]] = rng.choice(_WEIRD_VALUES)
    return tree


def toml_mutation(data: bytes, rng: random.Random) -> bytes:
    """Half the cases damage the bytes, half change one value of the parsed TOML."""
    if rng.random() < 0.5:
        return mutate_bytes(data, rng)
    tree = mutate_tree(tomllib.loads(data.decode()), rng)
    try:
        return tomli_w.dumps(tree).encode()
    except (TypeError, ValueError):  # a value TOML cannot hold
        return mutate_bytes(data, rng)


def json_lines_mutation(data: bytes, rng: random.Random) -> bytes:
    """Damage the bytes, or change one value of one JSON line."""
    if rng.random() < 0.5:
        return mutate_bytes(data, rng)
    lines = data.decode().splitlines()
    k = rng.randrange(len(lines))
    lines[k] = json.dumps(mutate_tree(json.loads(lines[k]), rng))
    return ("\n".join(lines) + "\n").encode()


# ---------------------------------------------------------------------------- checks


@contextlib.contextmanager
def no_hang(seconds: int = HANG_S) -> Iterator[None]:
    """Fail a case that runs longer than ``seconds`` (where the platform has SIGALRM)."""
    if not hasattr(signal, "SIGALRM"):
        yield
        return

    def hang(*_: Any) -> None:
        raise AssertionError(f"hung for over {seconds} s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def nonfinite(obj: Any, where: str = "") -> str | None:
    """The first NaN or infinity in a loaded structure, by its path; None if there is none."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            if (found := nonfinite(getattr(obj, f.name), f"{where}.{f.name}")) is not None:
                return found
    elif isinstance(obj, tuple | list):
        for i, value in enumerate(obj):
            if (found := nonfinite(value, f"{where}[{i}]")) is not None:
                return found
    elif isinstance(obj, float) and not math.isfinite(obj):
        return f"{where} = {obj}"
    elif isinstance(obj, np.ndarray) and obj.dtype.kind == "f" and not np.isfinite(obj).all():
        return f"{where} holds NaN or infinity"
    return None


def read_case(
    call: Callable[[Path], Any], path: Path, sane: Callable[[Any], str | None] | None = None
) -> None:
    """Read ``path``: a sane result, or a one-line ScratchfabError naming the file.

    Numpy warnings (overflow, invalid value) count as failures: the user would see them.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            with no_hang():
                result = call(path)
        except ScratchfabError as exc:
            text = str(exc)
            assert "\n" not in text and "\r" not in text, text
            assert str(path) in text, text
            return
    if sane is not None:
        problem = sane(result)
        assert problem is None, f"accepted nonsense: {problem}"


def special_paths(folder: Path, suffix: str) -> list[Path]:
    """A folder, an empty file, a missing file, a symlink loop and a dangling symlink."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"folder{suffix}").mkdir()
    (folder / f"empty{suffix}").write_bytes(b"")
    paths = [folder / f"folder{suffix}", folder / f"empty{suffix}", folder / f"missing{suffix}"]
    with contextlib.suppress(OSError, NotImplementedError):  # no symlinks on this system
        (folder / f"loop{suffix}").symlink_to(folder / f"loop{suffix}")
        (folder / f"dangling{suffix}").symlink_to(folder / "nowhere")
        paths += [folder / f"loop{suffix}", folder / f"dangling{suffix}"]
    return paths


# ---------------------------------------------------------------------------- seeds


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Valid files for every reader: the bundled ones, or made by the writers."""
    folder = tmp_path_factory.mktemp("seeds")
    out = {
        "design": ROOT / "pipelines" / "example" / "design.toml",
        "pipeline": bundled_dir("pipelines") / "demo.toml",
        "profile": ROOT / "machine_profiles" / "grbl-3018-diamond.toml",
        "servo": ROOT / "machine_profiles" / "grbl-plotter-scribe.toml",
    }
    rows = (ROOT / "pipelines" / "example" / "scratches.csv").read_text().splitlines()[:16]
    out["csv"] = folder / "scratches.csv"
    out["csv"].write_text("\n".join(rows) + "\n")
    out["csv6"] = folder / "scratches6.csv"
    out["csv6"].write_text(
        "x0,y0,x1,y1,width,depth\n" + "".join(f"{r},0.1,0.015\n" for r in rows[1:])
    )
    out["gcode"] = folder / "job.gcode"
    out["gcode"].write_text(GCODE)
    program = load_program(out["gcode"])
    out["journal"] = folder / "job.gcode.journal.jsonl"
    journal = Journal(out["journal"]).open()
    journal.start(program, resume=False, protocol="counting")
    for block in program.blocks[:7]:
        journal.write("ack", i=block.index, line=block.lineno)
    journal.write("lost", reason="link", executed_through=5)
    journal.close()
    out["npy"] = folder / "target.npy"
    np.save(out["npy"], np.linspace(0.0, 1.0, 48).reshape(6, 8))
    out["npz"] = folder / "checkpoint.npz"
    save_checkpoint(out["npz"], {"raw_x": np.arange(4.0)}, {"rng": {}}, np.zeros((2, 3)))
    ramp = np.arange(256, dtype=np.uint8).reshape(16, 16)
    out["png"] = folder / "target.png"
    Image.fromarray(ramp).save(out["png"])
    out["jpg"] = folder / "target.jpg"
    Image.fromarray(ramp).convert("RGB").save(out["jpg"], quality=90)
    out["tif"] = folder / "target.tif"
    Image.fromarray(ramp.astype(np.float32) / 255).save(out["tif"])
    out["manifest"] = folder / "manifest.json"
    stages = {
        "design": {"status": "done", "inputs": {"a": "1"}, "outputs": ["design"], "seconds": 1},
        "optimize": {"status": "running", "inputs": {"b": "2"}},
    }
    out["manifest"].write_text(json.dumps({"stages": stages}, indent=1))
    return out


def _program_sane(program: Any) -> str | None:
    for block in program.blocks:
        m = block.modal
        for value in (m.x, m.y, m.z, m.feed, m.speed, block.seconds):
            if value is not None and not math.isfinite(value):
                return f"line {block.lineno}: {value}"
    return None


def _read_program(path: Path) -> Any:
    program = load_program(path)
    check_tool_up_at_end(program)
    if program.blocks:
        job_extent(program)
    return program


def _read_journal(program_file: Path) -> Callable[[Path], Any]:
    program = load_program(program_file)

    def read(path: Path) -> Any:
        events = read_journal(path)
        if events:
            done_blocks(events, program.sha256, path, program=program)
            done_blocks(events, program.sha256, path, recut_unsure=True)
        return events

    return read


def _read_manifest(path: Path) -> Any:
    # The manifest is a cache: a damaged one is read as empty or partly empty, never an error.
    manifest = Manifest.load(path.parent)
    for stage in ("design", "optimize", "other"):
        manifest.is_current(stage, {"a": "1"})
        manifest.stopped(stage)
    return manifest


def _image_sane(image: np.ndarray) -> str | None:
    if image.ndim != 2 or not np.isfinite(image).all() or image.min() < 0 or image.max() > 1:
        return f"image {image.shape} outside [0, 1] or not finite"
    return None


READERS: dict[str, tuple[list[str], str, Any, Any, Any]] = {
    # name: (seed keys, suffix, reader (seeds -> callable), sanity check, mutation)
    "load_toml": (["design", "profile"], ".toml", lambda s: load_toml, None, mutate_bytes),
    "load_design": (
        ["design", "pipeline"],
        ".toml",
        lambda s: load_design,
        nonfinite,
        toml_mutation,
    ),
    "load_pipeline": (
        ["pipeline"],
        ".toml",
        lambda s: load_pipeline,
        lambda p: nonfinite(p.design) or nonfinite(p.optimize) or nonfinite(p.profile),
        toml_mutation,
    ),
    "load_profile": (
        ["profile", "servo"],
        ".toml",
        lambda s: load_profile,
        nonfinite,
        toml_mutation,
    ),
    "load_scratches": (
        ["csv", "csv6"],
        ".csv",
        lambda s: lambda p: load_scratches(p, (d := load_design(s["design"])).scratch, d.board),
        nonfinite,
        mutate_bytes,
    ),
    "load_program": (["gcode"], ".gcode", lambda s: _read_program, _program_sane, mutate_bytes),
    "read_journal": (
        ["journal"],
        ".jsonl",
        lambda s: _read_journal(s["gcode"]),
        None,
        json_lines_mutation,
    ),
    "load_numpy": (["npy"], ".npy", lambda s: load_numpy, None, mutate_bytes),
    "load_checkpoint": (["npz"], ".npz", lambda s: load_checkpoint, None, mutate_bytes),
    "load_image": (["png", "jpg", "tif"], ".png", lambda s: load_image, _image_sane, mutate_bytes),
    "manifest": (["manifest"], ".json", lambda s: _read_manifest, None, mutate_bytes),
}


@pytest.mark.parametrize("name", sorted(READERS))
def test_fuzzed_files_give_one_line_naming_the_file(name, seeds, tmp_path):
    keys, suffix, make_reader, sane, mutation = READERS[name]
    read = make_reader(seeds)
    if name != "manifest":
        for path in special_paths(tmp_path / "special", suffix):
            read_case(read, path)
    rng = random.Random(f"{name}-20240611")
    originals = [seeds[k].read_bytes() for k in keys]
    case = tmp_path / "job" / f"case{suffix}"
    if name == "manifest":
        case = case.with_name("manifest.json")
    case.parent.mkdir()
    for k in range(CASES):
        data = mutation(rng.choice(originals), rng)
        case.write_bytes(data)
        try:
            read_case(read, case, sane)
        except AssertionError as exc:
            raise AssertionError(f"case {k}: {exc}; input {data[:300]!r}") from None


# ---------------------------------------------------------------------------- findings


def _npy_header(header: dict[str, Any]) -> bytes:
    text = repr(header).encode()
    text += b" " * (-(10 + len(text) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text


def _design_text(**edits: str) -> str:
    text = (ROOT / "pipelines" / "example" / "design.toml").read_text()
    for old, new in edits.items():
        assert old in text
        text = text.replace(old, new)
    return text


def _npz_bytes(**arrays: Any) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _npz_needing_zip_version_25(**arrays: Any) -> bytes:
    data = bytearray(_npz_bytes(**arrays))
    central = data.index(b"PK\x01\x02")
    data[central + 6 : central + 8] = struct.pack("<H", 255)  # version needed to extract
    return bytes(data)


def _zip(members: dict[str, bytes]) -> bytes:
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buf.getvalue()


def _checkpoint_with_meta(meta: bytes) -> bytes:
    return _npz_bytes(meta=np.frombuffer(meta, dtype=np.uint8), log_rows=np.zeros((1, 2)))


# (reader, file name, content, expected message part)
FINDINGS: list[tuple[Callable[[Path], Any], str, bytes, str]] = [
    # tomllib raises ValueError, not TOMLDecodeError, for an integer of over 4300 digits
    (load_toml, "a.toml", b"a = " + b"9" * 5000, "an integer of more than 4300 digits"),
    (load_toml, "a.toml", b"a = " + b"[" * 5000, "nested too deeply"),
    # an integer beyond the float range in a float key: OverflowError in float()
    (
        load_design,
        "a.toml",
        _design_text(**{"intensity = 1.0": "intensity = 1" + "0" * 400}).encode(),
        "light.intensity: expected a finite number, got an integer of 401 digits",
    ),
    # coordinates near the float limit overflowed numpy (RuntimeWarning lines before the error)
    (
        load_design,
        "a.toml",
        _design_text(**{"[-180.0, 0.0, 500.0]": "[-1e308, 0.0, 500.0]"}).encode(),
        "views[0].position_mm: expected a value in [-1000000.0, 1000000.0], got -1e+308",
    ),
    (
        load_design,
        "a.toml",
        _design_text(**{"depth_mm = 0.015": "depth_mm = 1e-300"}).encode(),
        "scratch: width_mm 0.1 and depth_mm 1e-300: depth/width = 1e-299: expected 1e-09 to 30",
    ),
    (
        load_design,
        "a.toml",
        _design_text(**{"width_mm = 0.1": "width_mm = 100"}).encode(),
        "scratch.width_mm: expected at most the board's 60 mm side, got 100",
    ),
    # a tolerance finer than 6 decimals can write: math.ceil(inf) OverflowError
    (
        load_profile,
        "p.toml",
        (ROOT / "machine_profiles" / "grbl-3018-diamond.toml")
        .read_bytes()
        .replace(b"tolerance_mm = 0.01", b"tolerance_mm = 5e-324"),
        "no gcode.decimals (at most 6) meets it",
    ),
    # a cell longer than Python's csv field limit: _csv.Error
    (
        lambda p: load_scratches(p, load_design(ROOT / "pipelines/example/design.toml").scratch),
        "s.csv",
        b"x0,y0,x1,y1\n0,0,1," + b"1" * 200_000 + b"\n",
        "line 2: not CSV (field larger than field limit",
    ),
    # a dent wider than the board, or flat beyond what eq. 2 resolves, rendered with warnings
    (
        lambda p: load_scratches(
            p, (d := load_design(ROOT / "pipelines/example/design.toml")).scratch, d.board
        ),
        "s.csv",
        b"x0,y0,x1,y1,width,depth\n0,0,5,5,1e308,0.01\n",
        "line 2: column width: expected a positive size at most the board's 60 mm side",
    ),
    (
        lambda p: load_scratches(p, load_design(ROOT / "pipelines/example/design.toml").scratch),
        "s.csv",
        b"x0,y0,x1,y1,width,depth\n0,0,5,5,0.1,1e-300\n",
        "line 2: columns width and depth: depth/width = 1e-299",
    ),
    # json raises ValueError (not JSONDecodeError) or RecursionError
    (
        read_journal,
        "j.jsonl",
        b'{"ev":"start","sha256":"x","blocks":1,"resume":false}\n{"ev":"ack","i":'
        + b"9" * 5000
        + b"}\n",
        ":2: not a journal line",
    ),
    (
        read_journal,
        "j.jsonl",
        b'{"ev":"start","sha256":"x","blocks":1,"resume":false}\n' + b"[" * 100_000 + b"\n",
        ":2: not a journal line",
    ),
    # numpy allocates what the header says before reading: MemoryError
    (
        load_numpy,
        "a.npy",
        _npy_header({"descr": "<f8", "fortran_order": False, "shape": (10**12,)}),
        "the header says shape (1000000000000,) of float64 (8000000000000 bytes) but 0 bytes",
    ),
    (
        load_numpy,
        "a.npz",
        _zip({"a.npy": _npy_header({"descr": "<f8", "fortran_order": False, "shape": (10**12,)})}),
        "member 'a.npy': Failed to read its data: the header says shape (1000000000000,)",
    ),
    # numpy parses the header with tokenize: TokenError
    (load_numpy, "a.npy", b"\x93NUMPY\x01\x00\x0a\x00{'descr':'\n", "(a damaged header)"),
    # zipfile: NotImplementedError for a version it lacks
    (load_numpy, "a.npz", _npz_needing_zip_version_25(a=np.zeros(3)), "zip file version 25.5"),
    # a member that is not an array came back as bytes (AttributeError in the checkpoint)
    (load_checkpoint, "c.npz", _zip({"meta": b'{"format": 1}'}), "member 'meta' is not an .npy"),
    (load_checkpoint, "c.npz", _checkpoint_with_meta(b"[1, 2]"), "must be JSON objects"),
    (load_checkpoint, "c.npz", _checkpoint_with_meta(b'{"fingerprint": 3}'), "meta.fingerprint"),
    # a long name that is neither a bundled profile nor a file: OSError from is_file()
    (lambda p: load_profile("x" * 5000), "unused", b"", "not a bundled profile"),
]


@pytest.mark.parametrize("read, name, content, message", FINDINGS)
def test_each_finding_is_one_line_naming_the_file(tmp_path, read, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(ScratchfabError) as info:
            read(path)
    text = str(info.value)
    assert message in text and "\n" not in text
    if name != "unused":
        assert str(path) in text


def test_float_image_with_nan_pixels_is_refused_not_read_as_off_the_board(tmp_path):
    values = np.full((4, 5), 0.5, dtype=np.float32)
    values[2, 3] = np.nan
    values[3, 0] = np.inf
    path = tmp_path / "t.tif"
    Image.fromarray(values).save(path)
    with pytest.raises(ConfigError) as info:
        load_image(path)
    assert str(info.value) == (
        f"{path}: pixel (row 2, column 3) is nan; expected finite brightness values "
        "(2 pixels are NaN or infinite)"
    )
    values[2, 3] = values[3, 0] = 0.25  # the same file with finite values reads
    Image.fromarray(values).save(path)
    assert np.isfinite(load_image(path)).all()


def test_damaged_manifest_entries_read_as_not_done(tmp_path):
    job = tmp_path / "job"
    job.mkdir()
    (job / "out.txt").write_text("x")
    good = {"status": "done", "inputs": {"a": "1"}, "outputs": ["out.txt"]}
    stages = {
        "design": good,
        "optimize": 3,
        "verify": [1, 2],
        "toolpath": {**good, "outputs": 0},
        "export": {**good, "outputs": [0]},
        "stream": {**good, "outputs": ["a" * 5000]},
    }
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))
    manifest = Manifest.load(job)
    assert sorted(manifest.stages) == ["design", "stream"]
    assert manifest.is_current("design", {"a": "1"})
    for stage in ("optimize", "verify", "toolpath", "export", "stream"):
        assert not manifest.is_current(stage, {"a": "1"})
        assert not manifest.stopped(stage)


def _cli(args: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = scratchfab.cli.main(args)
        except SystemExit as exc:
            code = exc.code
    return int(code or 0), err.getvalue()


def test_render_cli_names_a_csv_cell_over_the_field_limit_and_writes_nothing(tmp_path):
    csv_file = tmp_path / "s.csv"
    csv_file.write_text("x0,y0,x1,y1\n0,0,1,1\n0,0,1," + "2" * 200_000 + "\n")
    out = tmp_path / "render"
    code, err = _cli(
        ["render", "--design", str(ROOT / "pipelines/example/design.toml"), "--scratches",
         str(csv_file), "--out", str(out)]
    )  # fmt: skip
    assert code == 2
    assert err.startswith(f"error: {csv_file}: line 3: not CSV") and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("lineno", [6, 9, 10])  # after a cut, a plunge, a cut
def test_stream_refuses_a_file_cut_short_with_the_tool_down(tmp_path, lineno):
    """A file cut at its first plunge shows no cutting height yet (no stroke): not caught."""
    gcode = tmp_path / "job.gcode"
    gcode.write_text("".join(GCODE.splitlines(keepends=True)[:lineno]))
    code, err = _cli(["stream", str(gcode), "--port", "grblsim://?time_scale=0", "--yes"])
    assert code == 2
    assert err == (
        f"error: {gcode}:{lineno}: the program ends with the tool down (Z -0.2 mm, below the "
        "cutting threshold 0.9); the file may be cut short: expected its last stroke to lift "
        "the tool (Z up or M5)\n"
    )
    assert not (tmp_path / "job.gcode.journal.jsonl").exists()  # nothing was sent
    gcode.write_text(gcode.read_text() + "G0 Z2\n")  # lifted: the stream runs
    code, err = _cli(["stream", str(gcode), "--port", "grblsim://?time_scale=0", "--yes"])
    assert code == 0, err


def test_a_servo_file_cut_short_with_the_pen_down_is_refused(tmp_path):
    gcode = tmp_path / "pen.gcode"
    gcode.write_text(
        "G21 G90\nG0 X1 Y1\nM3 S1000\nG1 X5 Y1 F600\nM5\nG0 X5 Y3\nM3 S1000\nG1 X1 Y3\n"
    )
    with pytest.raises(
        ConfigError,
        match=r"pen\.gcode:8: the program ends with the tool down \(spindle output M3\)",
    ):
        check_tool_up_at_end(load_program(gcode))
    gcode.write_text(gcode.read_text() + "M5\n")
    check_tool_up_at_end(load_program(gcode))


def test_the_mutations_reach_the_readers_checks(seeds, tmp_path):
    """The fuzz loop is not vacuous: its cases hit both outcomes for every reader."""
    rng = random.Random(5)
    for name in ("load_design", "load_scratches", "load_program", "read_journal"):
        keys, suffix, make_reader, _, mutation = READERS[name]
        read = make_reader(seeds)
        outcomes = set()
        for _ in range(40):
            path = tmp_path / f"probe{suffix}"
            path.write_bytes(mutation(seeds[keys[0]].read_bytes(), rng))
            try:
                read(path)
                outcomes.add("read")
            except ScratchfabError:
                outcomes.add("refused")
        assert outcomes == {"read", "refused"}, name


def test_os_errors_are_one_line(tmp_path):
    if os.name != "posix" or os.geteuid() == 0:
        pytest.skip("needs a POSIX user that file permissions apply to")
    path = tmp_path / "locked.toml"
    path.write_text("a = 1\n")
    path.chmod(0)
    with pytest.raises(ConfigError, match="cannot read"):
        load_toml(path)


def _toolpath_text(**edits: Any) -> bytes:
    """A planned toolpath's JSON with top-level keys replaced (values as JSON text)."""
    from scratchfab.model.design import Board
    from scratchfab.model.scratches import ScratchSet
    from scratchfab.toolpath import plan_toolpath

    n = 3
    p0 = np.array([[-10.0, -10.0], [0.0, 5.0], [8.0, -3.0]])
    scratches = ScratchSet(p0, p0 + [4.0, 1.0], np.full(n, 0.1), np.full(n, 0.01))
    plan = plan_toolpath(
        scratches, Board(width_mm=60.0, height_mm=60.0), load_profile("grbl-plotter-scribe")
    )
    data = json.loads(plan.to_json())
    text = json.dumps({**data, **{k: "@" + k for k in edits}})
    for key, value in edits.items():
        text = text.replace(f'"@{key}"', value)
    return text.encode()


@pytest.mark.parametrize(
    "edits, message",
    [
        ({"source_rows": "[" + "9" * 5000 + ", 1, 2]"}, "not a toolpath JSON file"),
        ({"statistics": "[" * 100_000}, "not a toolpath JSON file"),
        ({"source_rows": f"[{2**70}, 1, 2]"}, "malformed toolpath"),
        ({"outline_mm": "[[NaN, 0], [1, 0], [1, 1], [0, 1]]"}, "outline_mm must be finite"),
        ({"board_mm": "[Infinity, 60]"}, "board_mm must be finite"),
        ({"board_mm": "[-60, 60]"}, "board_mm must be positive"),
    ],
)
def test_a_damaged_toolpath_json_is_one_line_and_exports_nothing(tmp_path, edits, message):
    """Toolpath.load (what export reads): tracebacks before, or NaN written into SVG/DXF."""
    from scratchfab.toolpath import Toolpath

    path = tmp_path / "toolpath.json"
    path.write_bytes(_toolpath_text(**edits))
    with pytest.raises(ScratchfabError) as info:
        Toolpath.load(path)
    text = str(info.value)
    assert message in text and str(path) in text and "\n" not in text
    out = tmp_path / "board.svg"
    code, said = _cli(["export", "--toolpath", str(path), "-o", str(out)])
    assert code == 2 and message in said and not out.exists()


@pytest.mark.parametrize("name", ["manifest.json", "verify/metrics.json", "optimize/summary.json"])
def test_deeply_nested_job_json_does_not_break_the_report(tmp_path, name):
    """The report and the stale-layout check read these; RecursionError was not caught."""
    from scratchfab.model.job import stale_layout_warning
    from scratchfab.pipeline.report import _read_json

    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"[" * 100_000)
    assert _read_json(path) is None
    (tmp_path / "optimize").mkdir(exist_ok=True)
    (tmp_path / "optimize" / "scratches.csv").write_text("x0,y0,x1,y1\n")
    assert stale_layout_warning(tmp_path) is None


@pytest.mark.parametrize(
    "old, new, key",
    [
        ('target = "disc.png"', 'target = "disc\\u0000.png"', "target"),
        ('machine = "grbl-3018-diamond"', 'machine = "grbl\\u0000"', "machine"),
        ('port = "grblsim://', 'port = "\\u0000grblsim://', "port"),
    ],
)
def test_a_nul_character_in_a_toml_string_is_named_not_a_traceback(tmp_path, old, new, key):
    """TOML's \\u0000 puts a NUL in a string, which no path or port can hold (Python raised
    'embedded null byte' from deep inside, e.g. resolving a target's path)."""
    from conftest import write_pipeline

    pipeline = write_pipeline(tmp_path, edits={old: new})
    code, err = _cli(["run", str(pipeline), "--out", str(tmp_path / "job")])
    assert code == 2, err
    assert err.startswith(f"error: {pipeline}: ") and err.count("\n") == 1
    assert f"{key}: expected a string without a NUL character" in err
    assert not (tmp_path / "job").exists()


def test_a_nul_byte_in_a_path_given_in_code_is_named_when_read_or_written(tmp_path):
    """Paths built in code reach the file layer, which names them (NUL shown as \\0)."""
    from scratchfab.fileio import read_input, write_text
    from scratchfab.model.design import ScratchTool, load_design
    from scratchfab.model.scratches import load_scratches
    from scratchfab.toolpath.plan import Toolpath

    bad = tmp_path / "a\0b.toml"
    plain = str(bad).replace("\0", "\\0")
    shown = re.escape(plain)
    with pytest.raises(ConfigError, match=rf"^{shown}: cannot read \(a path cannot hold a NUL"):
        read_input(bad, "a TOML file")
    with pytest.raises(ConfigError, match=rf"^{shown}: cannot read"):
        load_design(bad)
    for suffix in (".npy", ".npz"):  # not "unreadable NumPy file (embedded null byte)"
        npy = re.escape(str(bad.with_suffix(suffix)).replace("\0", "\\0"))
        with pytest.raises(ConfigError, match=rf"^{npy}: cannot read \(a path cannot hold"):
            load_numpy(bad.with_suffix(suffix))
    with pytest.raises(ScratchfabError, match=rf"^{shown}: cannot write \(a path cannot hold"):
        write_text(bad, "a = 1\n")
    with pytest.raises(ScratchfabError, match=r": cannot write \(a path cannot hold"):
        write_text(tmp_path / "a\0" / "b.toml", "a = 1\n")
    for read in (lambda p: load_scratches(p, ScratchTool()), Toolpath.load):
        with pytest.raises(ConfigError, match=rf"^{shown}: cannot read \(a path cannot hold"):
            read(bad)
    assert list(tmp_path.iterdir()) == []
    # any user-facing message shows a NUL it names (a job folder given in code, say)
    assert str(ScratchfabError(f"{bad}: job folder not found")) == f"{plain}: job folder not found"
