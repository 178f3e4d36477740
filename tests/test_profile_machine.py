from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely import affinity

from scratchfab.bundled import bundled_dir, bundled_names
from scratchfab.errors import ConfigError
from scratchfab.machine.profile import (
    gcode_number,
    load_profile,
    profile_from_mapping,
)
from scratchfab.model.schema import load_toml

ROOT = Path(__file__).resolve().parents[1]


def base_table() -> dict:
    return load_profile("grbl-3018-diamond").to_table()


def test_bundled_profiles_load_and_round_trip():
    names = bundled_names("machine_profiles")
    assert {"grbl-3018-diamond", "grbl-plotter-scribe"} <= set(names)
    for name in names:
        profile = load_profile(name)
        assert profile.dialect == "grbl-1.1"
        assert profile_from_mapping(profile.to_table(), "<again>") == profile
        assert load_profile(bundled_dir("machine_profiles") / f"{name}.toml") == profile
    assert load_profile("grbl-plotter-scribe").tool_control.mode == "servo"
    assert load_profile("grbl-3018-diamond").tool_control.mode == "z"


def test_repo_root_copies_match_the_bundled_files():
    root = sorted((ROOT / "machine_profiles").glob("*.toml"))
    assert [p.stem for p in root] == bundled_names("machine_profiles")
    for path in root:
        assert path.read_bytes() == (bundled_dir("machine_profiles") / path.name).read_bytes()
    assert (ROOT / "machine_profiles" / "README.md").is_file()


def test_envelope_fields_for_grbl_settings():
    p = load_profile("grbl-3018-diamond")
    assert p.envelope.max_travel_mm == (300.0, 180.0, 45.0)
    assert p.serial.baud == 115200 and p.serial.rx_buffer_bytes == 128
    assert p.gcode.max_line_length <= 79
    assert load_profile(p) is p  # a loaded profile passes through, for callers taking either
    assert len(p.motion.max_rate_mm_min) == 3 and len(p.motion.acceleration_mm_s2) == 3


def test_junction_deviation_is_optional_and_may_be_zero():
    """``[motion] junction_deviation_mm`` ($11) defaults to GRBL's 0.010; 0 (exact stops) is valid."""
    table = copy.deepcopy(base_table())
    del table["motion"]["junction_deviation_mm"]
    assert profile_from_mapping(table, "my.toml").motion.junction_deviation_mm == 0.010
    table["motion"]["junction_deviation_mm"] = 0
    assert profile_from_mapping(table, "my.toml").motion.junction_deviation_mm == 0.0
    for name in bundled_names("machine_profiles"):  # the bundled ones say it
        raw = load_toml(bundled_dir("machine_profiles") / f"{name}.toml")
        assert (
            raw["motion"]["junction_deviation_mm"]
            == load_profile(name).motion.junction_deviation_mm
        )


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("tool.widht_mm", 0.1, "did you mean 'width_mm'"),
        ("motion.junction_deviation", 0.02, "did you mean 'junction_deviation_mm'"),
        ("motion.junction_deviation_mm", -0.01, "motion.junction_deviation_mm"),
        ("feeds.engrave_mm_min", -5.0, "feeds.engrave_mm_min"),
        ("board.rotation_deg", 45, "rotation_deg"),
        ("board.origin", "middle", "board.origin"),
        ("start_mm", [10.0, 10.0], "start_mm (10, 10) is outside the envelope (X "),
        ("z.engrave_mm", -50.0, "z.engrave_mm (-50) is outside the envelope's Z "),
        ("z.safe_mm", -31.0, "safe_mm"),
        ("feeds.engrave_mm_min", 5000.0, "max rate"),
        ("envelope.x_mm", [0.0, -10.0], "x_mm"),
        ("tool_control.on", "T1 M6", "M6"),
        ("tool_control.off", "M5 (stop!)", "realtime"),
        ("tool_control.on", "M3 S{speed}", "template"),
        ("dialect", "marlin", "dialect"),
    ],
)
def test_bad_profiles_name_the_key(path, value, message):
    table = copy.deepcopy(base_table())
    node = table
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = value
    with pytest.raises(ConfigError, match="my.toml") as err:
        profile_from_mapping(table, "my.toml")
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def write_z_profile(path: Path, safe: float, cut: float, decimals: int) -> Path:
    path.write_text(
        f"""name = "z test"
[envelope]
x_mm = [-100.0, 0.0]
y_mm = [-100.0, 0.0]
z_mm = [-40.6, 0.5]
[z]
safe_mm = {safe!r}
engrave_mm = {cut!r}
[tool]
width_mm = 0.1
depth_mm = 0.01
tolerance_mm = 0.5
[gcode]
decimals = {decimals}
"""
    )
    return path


@pytest.mark.parametrize(
    ("safe", "cut", "decimals", "keys"),
    [
        (0.3, -0.04, 0, ("z.safe_mm", "z.engrave_mm")),  # both written as 0
        (0.0004, 0.0001, 3, ("z.safe_mm", "z.engrave_mm")),
        (0.5, -40.6, 0, ("z.engrave_mm",)),  # written as -41, below z_mm's -40.6
    ],
)
def test_z_heights_the_decimals_cannot_write_are_refused_on_load(
    tmp_path, safe, cut, decimals, keys
):
    path = write_z_profile(tmp_path / "m.toml", safe, cut, decimals)
    with pytest.raises(ConfigError) as err:
        load_profile(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "gcode.decimals" in text and "\n" not in text
    assert all(key in text for key in keys)
    # With more decimals the same heights are written apart and inside the envelope.
    profile = load_profile(write_z_profile(path, safe, cut, 6))
    written = [float(gcode_number(v, 6)) for v in (profile.z.engrave_mm, profile.z.safe_mm)]
    assert -40.6 <= written[0] < written[1] <= 0.5


@pytest.mark.parametrize(
    ("decimals", "tolerance", "need"),
    [(0, 0.01, 2), (1, 0.01, 2), (2, 0.01, None), (1, 0.05, None), (2, 0.004, 3), (0, 0.5, None)],
)
def test_decimals_that_round_beyond_the_tolerance_are_refused(tmp_path, decimals, tolerance, need):
    """Rounding moves a coordinate by up to half the last digit: never more than the tolerance."""
    path = write_z_profile(tmp_path / "m.toml", 0.5, -1.0, decimals)
    path.write_text(path.read_text().replace("tolerance_mm = 0.5", f"tolerance_mm = {tolerance}"))
    values = np.random.default_rng(0).uniform(-100, 0, 20000)
    moved = np.abs(np.array([float(gcode_number(v, decimals)) for v in values]) - values).max()
    if need is None:
        assert moved <= tolerance
        assert load_profile(path).gcode.decimals == decimals
        return
    assert moved > tolerance  # the brute-force rounding error the refusal is about
    with pytest.raises(ConfigError) as err:
        load_profile(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "tool.tolerance_mm" in text
    assert f"use gcode.decimals = {need} or more" in text
    path.write_text(path.read_text().replace(f"decimals = {decimals}", f"decimals = {need}"))
    assert load_profile(path).gcode.decimals == need


def test_unknown_name_lists_bundled(tmp_path):
    with pytest.raises(ConfigError, match="grbl-3018-diamond"):
        load_profile("no-such-machine")
    bad = tmp_path / "m.toml"
    bad.write_text("name = 'x'\n[envelope]\nx_mm = [0, 1]\ny_mm = [0, 1]\n")
    with pytest.raises(ConfigError, match="tool: missing required key"):
        load_profile(bad)
    table = load_toml(bundled_dir("machine_profiles") / "grbl-plotter-scribe.toml")
    assert profile_from_mapping(table, "x").feeds.travel_mm_min == 4000.0


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
@pytest.mark.parametrize(
    "origin", ["lower-left", "lower-right", "upper-left", "upper-right", "center"]
)
def test_board_placement_matches_shapely(rotation, origin):
    table = base_table()
    table["board"] = {"origin": origin, "offset_mm": [-150.0, -90.0], "rotation_deg": rotation}
    p = profile_from_mapping(table, "<t>")
    w, h = 60.0, 30.0
    rng = np.random.default_rng(rotation)
    pts = rng.uniform([-w / 2, -h / 2], [w / 2, h / 2], (20, 2))
    # Reference: rotate with shapely about the board centre, then move the named corner.
    board = shapely.box(-w / 2, -h / 2, w / 2, h / 2)
    turned = affinity.rotate(board, rotation, origin=(0, 0))
    minx, miny, maxx, maxy = turned.bounds
    anchor = {
        "lower-left": (minx, miny),
        "lower-right": (maxx, miny),
        "upper-left": (minx, maxy),
        "upper-right": (maxx, maxy),
        "center": (0.0, 0.0),
    }[origin]
    dx, dy = -150.0 - anchor[0], -90.0 - anchor[1]
    ref = [
        affinity.translate(affinity.rotate(shapely.Point(q), rotation, origin=(0, 0)), dx, dy)
        for q in pts
    ]
    want = np.array([[r.x, r.y] for r in ref])
    assert np.allclose(p.board_to_machine(pts, (w, h)), want, atol=1e-9)
    outline = shapely.Polygon(p.board_outline((w, h)))
    assert outline.is_valid and outline.exterior.is_ccw
    assert outline.equals_exact(affinity.translate(turned, dx, dy).normalize(), 1e-9) or (
        outline.symmetric_difference(affinity.translate(turned, dx, dy)).area < 1e-9
    )


@pytest.mark.parametrize(
    ("key", "template", "message"),
    [
        ("off", "$RST=*", "not a list of G-code words"),  # a settings reset on every stroke
        ("off", "$J=G91 X-500 F1000", "not a list of G-code words"),  # a jog past the envelope
        ("off", "M5 G0 X-900", "G0 is not a tool command"),  # a move the export never checks
        ("off", "M5 X-900", "X words do not belong"),
        ("on", "G10 L2 P1 X0", "G10 is not a tool command"),
        ("on", "M3 S{power}\u000b$RST=*", "printable ASCII"),  # VT: a line end to some readers
        ("on", "M3 S{power}\u0018", "printable ASCII"),  # Ctrl-X: GRBL's soft reset
        ("on", "M3 S{power.__class__}", "only {power}"),
        ("on", "M3 S{power!r}", "only {power}"),
        ("off", "", "not a list of G-code words"),  # the scribe would never lift
        ("off", "(lift)", "not a list of G-code words"),
        ("off", "M3 S{power}", "same command"),
        ("on", "M3 S{power} G4", "G4 needs its P"),
        ("on", "M3 S-5", "negative"),
        ("off", "M5 ; up", "not a list of G-code words"),
    ],
)
def test_tool_commands_only_switch_the_tool(key, template, message):
    """Sent once per stroke: anything beyond M3/M4/M5, coolant, S and a dwell is refused."""
    table = copy.deepcopy(base_table())
    table["tool_control"] = {"mode": "spindle", key: template}
    with pytest.raises(ConfigError) as err:
        profile_from_mapping(table, "my.toml")
    text = str(err.value)
    assert text.startswith("my.toml: ") and message in text and "\n" not in text


@pytest.mark.parametrize(
    ("on", "off"),
    [
        ("M3 S{power}", "M5"),
        ("M3S{power}", "M3 S10 (pen up)"),  # a servo lifted by another angle
        ("M4 S{power} G4 P0.2", "M5 M9"),
        ("m3 s{power} m8", "m5"),
    ],
)
def test_tool_commands_that_switch_the_tool_load(on, off):
    table = copy.deepcopy(base_table())
    table["tool_control"] = {"mode": "spindle", "on": on, "off": off, "power": 60}
    control = profile_from_mapping(table, "my.toml").tool_control
    assert control.command("on") == on.format(power="60")


def test_a_profile_name_is_one_printable_line():
    table = copy.deepcopy(base_table())
    table["name"] = "shop\nmill\x18"
    with pytest.raises(ConfigError, match="control characters"):
        profile_from_mapping(table, "my.toml")
    table["name"] = "Fräse (Werkstatt), 3018"
    assert profile_from_mapping(table, "my.toml").name == "Fräse (Werkstatt), 3018"
