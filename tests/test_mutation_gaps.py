"""Machine-safety behaviour that a mutation review found no test would miss if it broke.

The order of the feed hold and the soft reset when connecting to a controller that is still
moving; the positions derived from status reports (MPos/WPos, WCO, inch reports); the
planner/sync rule of :func:`last_surely_run`; the per-axis feed limits of a profile; stroke
detection on odd jobs; :func:`merge_collinear` against a brute-force duplicate relation.
Each test compares with a reference written here, not with the code under test.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from gcode_interp import interpret
from hypothesis import given, settings
from hypothesis import strategies as st

from scratchfab.errors import ConfigError
from scratchfab.machine.grblsim import GrblSim, SimOptions
from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.machine.sender import (
    Streamer,
    StreamOptions,
    open_port,
    parse_status,
)
from scratchfab.machine.sender_journal import last_surely_run
from scratchfab.machine.sender_program import load_program, strip_block
from scratchfab.toolpath.geometry import merge_collinear

INCH = 25.4

# --------------------------------------------------------------------------- 1. busy connect


class _SimPort:
    """A port straight onto a :class:`GrblSim` that keeps every byte the sender wrote."""

    def __init__(self, sim: GrblSim) -> None:
        self.sim = sim
        self.timeout: float | None = 0.01
        self.sent = bytearray()

    def write(self, data: bytes) -> int:
        self.sent += data
        return self.sim.host_write(bytes(data))

    def read(self, size: int = 1) -> bytes:
        return self.sim.host_read(size, self.timeout)

    @property
    def in_waiting(self) -> int:
        return self.sim.host_in_waiting()

    def reset_input_buffer(self) -> None:
        self.sim.host_flush_input()

    def close(self) -> None:
        pass


def _sim_lines(sim: GrblSim, until, timeout: float = 3.0) -> list[str]:
    """Lines the emulator sent, read until ``until(lines)`` holds."""
    buf, lines = b"", []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        buf += sim.host_read(4096, 0.02)
        *done, buf = buf.split(b"\n")
        lines += [d.decode().strip() for d in done if d.strip()]
        if until(lines):
            return lines
    raise AssertionError(f"emulator timeout; got {lines!r}")


@pytest.mark.parametrize(
    ("queued", "state", "stopped"),
    [(b"G21G90\nG1X60F100\n", "Run", "Hold:0"), (b"$J=G21G91X60F100\n", "Jog", "Idle")],
)
def test_a_controller_still_moving_at_connect_is_held_before_the_soft_reset(queued, state, stopped):
    """A killed sender's queue still runs (360 s, scaled) past ``busy_timeout``: the
    sender sends ``!``, waits for the machine to stop (Hold:0; a hold cancels a jog, which
    ends Idle), and only then 0x18; before the reset it writes nothing but status requests
    and that one hold. A reset mid-move would be ALARM:3."""
    sim = GrblSim(SimOptions(baud=0, time_scale=10.0))  # the hold takes 0.5 s: 2 polls
    sim.start()
    try:
        _sim_lines(sim, lambda ls: any(x.startswith("Grbl") for x in ls))
        sim.host_write(queued)
        _sim_lines(sim, lambda ls: ls.count("ok") == queued.count(b"\n"))
        sim.host_flush_input()
        port = _SimPort(sim)
        said: list[str] = []
        options = StreamOptions(
            banner_timeout=0.3, banner_settle=0.02, busy_timeout=0.3, hold_timeout=3.0
        )
        info = Streamer(port, options, on_message=said.append).connect()
    finally:
        sim.close(drain_timeout=0.0)
    sent = bytes(port.sent)
    reset = sent.index(b"\x18")
    assert set(sent[:reset]) <= {ord("?"), ord("!")}, sent[:reset]
    assert sent[:reset].count(b"!") == 1
    assert sent[reset + 1 :].replace(b"?", b"").startswith(b"$I\n")
    assert any(f"still moving ({state})" in s for s in said)
    assert any(f"still {state} after 0.3 s: feed hold, then a soft reset" in s for s in said)
    rec = sim.record
    t_hold = next(e["t"] for e in rec if e["ev"] == "rt" and e["ch"] == ord("!"))
    t_held = next(
        e["t"] for e in rec if e["ev"] == "state" and e["state"] == stopped and e["t"] >= t_hold
    )
    t_reset = next(e["t"] for e in rec if e["ev"] == "reset" and e["command"])
    assert t_hold <= t_held <= t_reset
    assert not [e for e in rec if e["ev"] == "alarm"]
    assert not [e for e in rec if e["ev"] == "exec" and e["to"][0] == 60.0]  # cut short
    assert info.status.state == "Idle"


# --------------------------------------------------------------------------- 2. status


_coord = st.integers(-500_000, 500_000).map(lambda k: k / 1000.0)
_xyz = st.tuples(_coord, _coord, _coord)


def _text(v: tuple[float, float, float], inches: bool) -> str:
    """Numbers as GRBL prints them: 3 decimals in mm, 4 in inches."""
    return ",".join(f"{c / INCH:.4f}" if inches else f"{c:.3f}" for c in v)


@settings(max_examples=150, deadline=None)
@given(
    key=st.sampled_from(["MPos", "WPos"]),
    pos=_xyz,
    field=st.one_of(st.none(), _xyz),
    remembered=st.one_of(st.none(), _xyz),
    inches=st.booleans(),
    feed=st.integers(0, 5000),
)
def test_parse_status_derives_the_other_position_by_hand(key, pos, field, remembered, inches, feed):
    """MPos - WCO = WPos (GRBL's definition); the report's own WCO wins over the remembered
    one, which is already in mm and is not scaled again; inch reports scale by 25.4."""
    scale = INCH if inches else 1.0
    parts = ["Run", f"{key}:{_text(pos, inches)}", "Bf:15,128", f"FS:{feed},0"]
    if field is not None:
        parts.append(f"WCO:{_text(field, inches)}")
    parts += ["Ov:100,100,100", "Pn:XZ"]
    line = "<" + "|".join(parts) + ">"
    got = parse_status(line, remembered, scale)

    reported = [float(c) * scale for c in _text(pos, inches).split(",")]
    if field is not None:
        wco = [float(c) * scale for c in _text(field, inches).split(",")]
    else:
        wco = None if remembered is None else list(remembered)
    if key == "MPos":
        mpos = reported
        wpos = None if wco is None else [reported[k] - wco[k] for k in range(3)]
    else:
        wpos = reported
        mpos = None if wco is None else [reported[k] + wco[k] for k in range(3)]
    assert got.state == "Run"
    assert got.feed == pytest.approx(feed * scale, abs=1e-9)
    for have, want in ((got.mpos, mpos), (got.wpos, wpos), (got.wco, wco)):
        if want is None:
            assert have is None
        else:
            assert have == pytest.approx(want, abs=1e-9)


def test_the_sender_remembers_the_last_wco_in_mm_for_the_next_reports():
    """A report without WCO (GRBL sends it every 10-30 reports) takes the last one seen;
    under $13=1 both the report and the offset were in inches."""
    s = Streamer(SimpleNamespace())  # type: ignore[arg-type]  (reports only)
    s.info.settings[13] = 1.0
    s._note_status("<Idle|MPos:1.0000,2.0000,-0.5000|FS:0,0|WCO:0.5000,-1.0000,0.2500>")
    assert s.status.wpos == pytest.approx([12.7, 76.2, -19.05], abs=1e-9)
    s._note_status("<Run|MPos:2.0000,0.0000,0.0000|FS:10,0>")
    assert s.status.wco == pytest.approx([12.7, -25.4, 6.35], abs=1e-9)
    assert s.status.wpos == pytest.approx([50.8 - 12.7, 25.4, -6.35], abs=1e-9)
    assert s.status.feed == pytest.approx(254.0)


_REPORTS = [
    pytest.param(1, 0, 1, id="MPos-mm-WCO"),
    pytest.param(0, 1, 1, id="WPos-inch-WCO"),
    pytest.param(1, 1, 1, id="MPos-inch-WCO"),
    pytest.param(0, 0, 0, id="WPos-mm-noWCO"),
    pytest.param(1, 0, 0, id="MPos-mm-noWCO"),  # the offset read with $# at connect
]


@pytest.mark.parametrize(("mpos", "inches", "wco_field"), _REPORTS)
def test_the_senders_work_position_is_the_emulators(mpos, inches, wco_field):
    """After moving to a known work position under a G54 offset, the sender's ``wpos`` is
    that position whichever report the controller sends ($10, $13, the WCO field)."""
    port = open_port(
        f"grblsim://?time_scale=0.01&wco=5,7,1&wco_field={wco_field}&$10={mpos}&$13={inches}",
        115200,
    )
    try:
        s = Streamer(port, StreamOptions(banner_timeout=0.5, banner_settle=0.02))
        s.connect()
        s._command("G21G90G0X12.344Y-6.788Z3.212")  # on the 250 steps/mm grid, with the offset
        deadline = time.monotonic() + 3.0
        while s._status_now().state != "Idle" and time.monotonic() < deadline:
            time.sleep(0.02)
        status = s._status_now()
    finally:
        port.close()
    assert status.wpos is not None
    # inch reports carry 4 decimals of an inch: 1.3 um per number, twice with WCO
    assert status.wpos == pytest.approx([12.344, -6.788, 3.212], abs=3e-3)


@pytest.mark.parametrize("inches", [0, 1])
def test_the_work_offset_read_with_dollar_hash_is_in_mm(inches):
    """$# gives G54 + G92 (+ TLO on Z); under $13=1 GRBL prints it in inches."""
    port = open_port(f"grblsim://?time_scale=0.01&wco=5,7,1&$13={inches}", 115200)
    try:
        s = Streamer(port, StreamOptions(banner_timeout=0.5, banner_settle=0.02))
        info = s.connect()
    finally:
        port.close()
    assert info.wco_source == "$#"
    assert info.wco == pytest.approx([5.0, 7.0, 1.0], abs=2e-3)


# --------------------------------------------------------------------------- 3. last_surely_run


def _blocks(kinds: list[str]) -> list[SimpleNamespace]:
    """Blocks of kinds m (a move), x (a sync block that moves), s (a sync block), o (other)
    and z (a straight move of no length: back to where the block before it ended)."""
    blocks = []
    x = 0.0
    for k, c in enumerate(kinds):
        x += c in "mx"
        modal = SimpleNamespace(motion="G1", x=x, y=0.0, z=-0.1, assumed="")
        blocks.append(
            SimpleNamespace(
                index=k,
                motion=c in "mxz",
                sync=c in "sx",
                text=c,
                modal=modal,
                unfollowed="",
                arc_box=None,
            )  # fmt: skip
        )
    return blocks


def _surely_run_reference(
    kinds: list[str], acked: list[int], pending: int, trust_last_sync: bool
) -> int:
    """Block by block: an acked block surely ran when a sync block acked at or after it
    (the controller empties its planner before answering one) or when at least
    ``pending`` motion blocks were acked after it (no more can wait unrun). A sync block
    that moves ("x": ``G1 X5 M3``) waits only for the moves before it, so it does not
    vouch for its own move. The answer is the block before the first one not sure to
    have run (the last acked if all are)."""
    n = len(acked)
    sure = []
    for p in range(n):
        later_sync = any(
            kinds[acked[q]] in "sx"
            and (q < n - 1 or trust_last_sync)
            and (q > p or kinds[acked[p]] == "s")
            for q in range(p, n)
        )
        motions_after = sum(kinds[acked[q]] in "mx" for q in range(p + 1, n))  # z: no block
        sure.append(later_sync or motions_after >= pending)
    unsure = [p for p in range(n) if not sure[p]]
    assert unsure == list(range(n - len(unsure), n))  # a suffix: the rule is monotone
    if not acked:
        return -1
    return acked[unsure[0]] - 1 if unsure else acked[-1]


_session = st.lists(st.sampled_from("mmmmsoxzz"), max_size=40).flatmap(
    lambda kinds: st.tuples(
        st.just(kinds),
        st.integers(0, len(kinds)),
        st.integers(0, len(kinds)),
        st.integers(0, 6),
    )
)


@settings(max_examples=400, deadline=None)
@given(_session)
def test_last_surely_run_matches_a_block_by_block_reference(session):
    """Contiguous acked runs (a session from its start block) of motion, sync and other
    blocks, small planners. The sender's rule: ``planner + 6`` motion blocks may be unrun
    (Grbl's stepper runs up to 5 blocks its planner let go, one more as a margin), and the
    last acked block counts as unsure even when it is a sync block."""
    kinds, a, b, planner = session
    lo, hi = min(a, b), max(a, b)
    acked = list(range(lo, hi))
    got = last_surely_run(_blocks(kinds), acked, planner)
    assert got == _surely_run_reference(kinds, acked, planner + 6, trust_last_sync=False)


@settings(max_examples=400, deadline=None)
@given(_session)
def test_last_surely_run_never_trusts_more_than_its_docstring_allows(session):
    """Safety: never later than "up to planner blocks plus the 5 Grbl's step segments may
    hold; an acked sync block means everything before it ran", read literally."""
    kinds, a, b, planner = session
    acked = list(range(min(a, b), max(a, b)))
    got = last_surely_run(_blocks(kinds), acked, planner)
    assert got <= _surely_run_reference(kinds, acked, planner + 5, trust_last_sync=True)


# --------------------------------------------------------------------------- 4. feed limits


def _profile_table(name: str, rates: list[float], **feeds: float) -> dict:
    table = load_profile(name).to_table()
    table["motion"]["max_rate_mm_min"] = rates
    table["feeds"].update(feeds)
    return table


def _axis_refuses(feed: float, rates: list[float]) -> bool:
    """An XY feed must be reachable along any direction: along X at rate X, along Y at Y."""
    along_x, along_y = feed <= rates[0], feed <= rates[1]
    return not (along_x and along_y)


@pytest.mark.parametrize("name", ["grbl-3018-diamond", "grbl-plotter-scribe"])
@pytest.mark.parametrize("key", ["engrave_mm_min", "travel_mm_min"])
@pytest.mark.parametrize(
    ("rates", "feed"),
    [
        ([3000.0, 1000.0, 400.0], 1500.0),  # above Y only
        ([1000.0, 3000.0, 400.0], 1500.0),  # above X only
        ([3000.0, 1000.0, 400.0], 1000.0),  # exactly Y's rate
        ([3000.0, 1000.0, 400.0], 999.0),
        ([2000.0, 2000.0, 400.0], 2000.5),
    ],
)
def test_xy_feeds_are_checked_against_both_axis_rates(name, key, rates, feed):
    """engrave (the servo job's cutting feed too) and travel: within X and Y, or refused
    with one line naming the file, the key and the limit."""
    others = {k: 100.0 for k in ("engrave_mm_min", "travel_mm_min") if k != key}
    table = _profile_table(name, rates, plunge_mm_min=100.0, **others, **{key: feed})
    if _axis_refuses(feed, rates):
        with pytest.raises(ConfigError) as err:
            profile_from_mapping(table, "my.toml")
        msg = str(err.value)
        assert msg.startswith("my.toml") and "\n" not in msg
        assert f"feeds.{key} ({feed:g})" in msg
        assert f"({min(rates[:2]):g} mm/min)" in msg
    else:
        profile = profile_from_mapping(table, "my.toml")
        assert getattr(profile.feeds, key) == feed


@pytest.mark.parametrize(
    ("name", "refused"), [("grbl-3018-diamond", True), ("grbl-plotter-scribe", False)]
)
def test_the_plunge_feed_is_checked_against_z_except_for_a_servo(name, refused):
    """A servo has no Z: its plunge feed is unused. A Z job plunges at most at Z's rate."""
    table = _profile_table(name, [5000.0, 5000.0, 300.0], plunge_mm_min=300.5)
    if refused:
        with pytest.raises(ConfigError, match=r"feeds\.plunge_mm_min \(300\.5\).*\(300 mm/min\)"):
            profile_from_mapping(table, "my.toml")
    else:
        assert profile_from_mapping(table, "my.toml").feeds.plunge_mm_min == 300.5
    table["feeds"]["plunge_mm_min"] = 300.0
    assert profile_from_mapping(table, "my.toml").feeds.plunge_mm_min == 300.0


# --------------------------------------------------------------------------- 5. strokes


_Z_OPS = {
    "down": "G1 Z-0.1 F100",
    "deeper": "G1 Z-0.2 F100",
    "edge": "G0 Z1",  # exactly at the threshold: up
    "below": "G1 Z0.999 F100",  # just under it: down
    "up": "G0 Z2",
    "cut": "G1 X{x} Y{y} F300",
    "travel": "G0 X{x} Y{y}",
    "feed": "F250",
    "comment": "(a comment)",
    "semi": "  ; remark",
    "blank": "",
}
_PEN_OPS = {
    "on": "M3 S40",
    "off": "M5",
    "cut": "G1 X{x} Y{y} F500",
    "travel": "G0 X{x} Y{y}",
    "dwell": "G4 P0.1",
    "end": "M2",  # GRBL takes lines after a program end; it turns the output off
    "comment": "( pen )",
    "blank": "",
}


def _job(ops: list[str], table: dict[str, str], head: list[str], end: bool) -> list[str]:
    lines = list(head)
    for k, op in enumerate(ops):
        lines.append(table[op].format(x=k % 7, y=(3 * k) % 5))
    if end:
        lines.append("M2")
    return lines


def _spans_reference(down_after_line: dict[int, bool]) -> list[tuple[int, int]]:
    """Strokes by file line: each maximal run of tool-down blocks, with the block that ends
    it (the lift), or up to the job's last block when the job ends down."""
    lines = sorted(down_after_line)
    spans, k = [], 0
    while k < len(lines):
        if not down_after_line[lines[k]]:
            k += 1
            continue
        j = k
        while j < len(lines) and down_after_line[lines[j]]:
            j += 1
        spans.append((lines[k], lines[min(j, len(lines) - 1)]))
        k = j + 1
    return spans


def _check_strokes(text: str, prog, want: list[tuple[int, int]]) -> None:
    got = [(prog.blocks[a].lineno, prog.blocks[b].lineno) for a, b in prog.strokes]
    assert got == want, text
    of = prog.stroke_of()
    for b in prog.blocks:
        inside = [k for k, (lo, hi) in enumerate(want) if lo <= b.lineno <= hi]
        assert of[b.index] == (inside[0] if inside else -1)


@settings(max_examples=120, deadline=None)
@given(ops=st.lists(st.sampled_from(sorted(_Z_OPS)), max_size=25), end=st.booleans())
def test_z_strokes_of_odd_jobs_match_the_interpreters_tool_heights(ops, end):
    """Strokes with no cutting move, repeated plunges, a job that ends with the tool down,
    comments and blank lines in between, Z exactly at the threshold (1 mm)."""
    lines = _job(ops, _Z_OPS, ["G21 G90", "G0 X0 Y0 Z2"], end)
    text = "\n".join(lines) + "\n"
    run = interpret(text)
    down: dict[int, bool] = {}
    z = 2.0  # the first positioning line
    moves = {m.line_no: m for m in run.moves}
    for no, raw in enumerate(lines, start=1):
        if no in moves:
            z = moves[no].end[2]
        if strip_block(raw):
            down[no] = z < 1.0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "job.gcode"
        path.write_text(text)
        prog = load_program(path, z_threshold=1.0)
    _check_strokes(text, prog, _spans_reference(down))


@settings(max_examples=120, deadline=None)
@given(ops=st.lists(st.sampled_from(sorted(_PEN_OPS)), max_size=25), end=st.booleans())
def test_servo_strokes_of_odd_jobs_follow_the_tool_output(ops, end):
    """Pen jobs (no Z): the output on (M3) is down, M5 and M2 lift; a job without M3 has
    no strokes. The interpreter's moves agree with the tool state tracked here."""
    lines = _job(ops, _PEN_OPS, ["G21 G90", "M5", "G0 X0 Y0"], end)
    text = "\n".join(lines) + "\n"
    run = interpret(text)
    down: dict[int, bool] = {}
    on = False
    for no, raw in enumerate(lines, start=1):
        block = strip_block(raw)
        if block.startswith("M3"):
            on = True
        elif block in ("M5", "M2"):
            on = False
        if block:
            down[no] = on
    for m in run.moves:
        assert m.spindle == down[m.line_no]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "job.gcode"
        path.write_text(text)
        prog = load_program(path)
    want = _spans_reference(down) if "on" in ops else []
    assert prog.pen_mode == ("on" in ops)
    _check_strokes(text, prog, want)


# --------------------------------------------------------------------------- 6. merge_collinear


TOL = 0.01


def _dist_to_line(q: np.ndarray, a0: np.ndarray, a1: np.ndarray) -> np.ndarray:
    d = (a1 - a0) / np.linalg.norm(a1 - a0)
    r = np.atleast_2d(q) - a0
    return np.abs(r[:, 0] * d[1] - r[:, 1] * d[0])


def _duplicates(p0, p1, a: int, b: int, tol: float) -> bool:
    """The docstring's relation: every endpoint of each within ``tol`` of the other's
    line, extents along it overlapping or meeting within ``tol``."""
    if _dist_to_line(np.stack([p0[b], p1[b]]), p0[a], p1[a]).max() > tol:
        return False
    if _dist_to_line(np.stack([p0[a], p1[a]]), p0[b], p1[b]).max() > tol:
        return False
    d = (p1[a] - p0[a]) / np.linalg.norm(p1[a] - p0[a])
    ta, tb = sorted([p0[a] @ d, p1[a] @ d]), sorted([p0[b] @ d, p1[b] @ d])
    return min(ta[1], tb[1]) >= max(ta[0], tb[0]) - tol


def _components(p0, p1, tol: float) -> set[frozenset[int]]:
    n = len(p0)
    parent = list(range(n))

    def root(k: int) -> int:
        while parent[k] != k:
            k = parent[k]
        return k

    for a in range(n):
        for b in range(a + 1, n):
            if _duplicates(p0, p1, a, b, tol):
                parent[root(a)] = root(b)
    groups: dict[int, set[int]] = {}
    for k in range(n):
        groups.setdefault(root(k), set()).add(k)
    return {frozenset(g) for g in groups.values()}


def _seg_dist(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances of points ``q`` (M, 2) to the segment a-b."""
    d = b - a
    t = np.clip(((q - a) @ d) / (d @ d), 0.0, 1.0)
    return np.linalg.norm(q - (a + t[:, None] * d), axis=1)


def _samples(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    n = int(np.ceil(np.linalg.norm(b - a) / step)) + 1
    t = np.linspace(0.0, 1.0, n)[:, None]
    return a + t * (b - a)


def _messy_set(rng: np.random.Generator, bases: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Random segments with exact and reversed duplicates, collinear overlaps, pieces that
    touch (gap <= tol/2) or stop short (gap 2 tol), parallel copies tol/2 off and 1.5 tol
    off (on the other side), a short piece tol/2 off, copies tilted by 2e-6 mm (across
    the angle's wrap at 180 degrees for the horizontal bases), copies turned about their
    middle so that their ends move 0.4 tol sideways, in random order."""
    segs = []
    for _ in range(bases):
        a = rng.uniform(-60, 60, 2)
        ang = rng.choice([0.0, rng.uniform(0, 2 * np.pi)])
        length = rng.uniform(0.5, 20.0)
        d = np.array([np.cos(ang), np.sin(ang)])
        nrm = np.array([-d[1], d[0]])
        b = a + length * d
        segs.append((a, b))
        pick = rng.choice(11, size=rng.integers(0, 6), replace=False)
        for kind in pick:
            if kind == 0:
                segs.append((a.copy(), b.copy()))
            elif kind == 1:
                segs.append((b.copy(), a.copy()))
            elif kind == 2:
                t0, t1 = rng.uniform(-0.5, 0.5) * length, rng.uniform(0.5, 1.5) * length
                segs.append((a + t0 * d, a + t1 * d))
            elif kind == 3:
                gap = rng.uniform(0.0, 0.5 * TOL)
                segs.append((b + gap * d, b + (gap + rng.uniform(0.2, 5.0)) * d))
            elif kind == 4:
                segs.append((b + 2 * TOL * d, b + (2 * TOL + rng.uniform(0.2, 5.0)) * d))
            elif kind == 5:
                segs.append((a + 0.5 * TOL * nrm, b + 0.5 * TOL * nrm))
            elif kind == 6:
                segs.append((b - 1.5 * TOL * nrm, a - 1.5 * TOL * nrm))
            elif kind == 7:
                segs.append((a + 0.2 * length * d, a + 0.7 * length * d))
            elif kind == 8:
                segs.append((a + 1e-6 * nrm, b - 1e-6 * nrm))
            elif kind == 10:
                segs.append(_rotated_copy(a, b, 0.4 * TOL))
            else:
                segs.append(
                    (a + 0.3 * length * d + 0.5 * TOL * nrm, a + 0.5 * length * d + 0.5 * TOL * nrm)
                )
    order = rng.permutation(len(segs))
    p0 = np.array([segs[k][0] for k in order])
    p1 = np.array([segs[k][1] for k in order])
    return p0, p1


def _check_merge(p0: np.ndarray, p1: np.ndarray, tol: float) -> None:
    q0, q1, groups = merge_collinear(p0, p1, tol)
    n = len(p0)
    assert sorted(int(k) for g in groups for k in g) == list(range(n))
    assert {frozenset(int(k) for k in g) for g in groups} == _components(p0, p1, tol)
    singles = [int(g[0]) for g in groups if len(g) == 1]
    assert singles == sorted(singles)
    assert all(len(g) == 1 for g in groups[: len(singles)])  # singles first
    for k, g in enumerate(groups):
        if len(g) == 1:
            assert np.array_equal(q0[k], p0[g[0]]) and np.array_equal(q1[k], p1[g[0]])
            continue
        # along the longest member's line (any of equal length)
        lengths = np.linalg.norm(p1[g] - p0[g], axis=1)
        longest = [m for m, n in zip(g, lengths, strict=True) if n >= lengths.max() - 1e-12]
        ends = np.stack([q0[k], q1[k]])
        assert min(_dist_to_line(ends, p0[m], p1[m]).max() for m in longest) <= 1e-9
        # every point of every member is covered, and the output covers nothing else
        for m in g:
            pts = _samples(p0[m], p1[m], tol / 4)
            assert _seg_dist(pts, q0[k], q1[k]).max() <= tol + 1e-9
        out = _samples(q0[k], q1[k], tol / 4)
        near = np.min([_seg_dist(out, p0[m], p1[m]) for m in g], axis=0)
        assert near.max() <= tol + 1e-9
    for a in range(len(q0)):  # nothing left to merge
        for b in range(a + 1, len(q0)):
            assert not _duplicates(q0, q1, a, b, tol)


@pytest.mark.parametrize("seed", range(12))
def test_merge_collinear_matches_the_brute_force_duplicate_groups(seed):
    p0, p1 = _messy_set(np.random.default_rng(seed))
    _check_merge(p0, p1, TOL)


def _rotated_copy(a, b, delta):
    """``a``-``b`` turned about its middle so that its ends move ``delta`` sideways."""
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    ang = delta / np.linalg.norm(half)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    return mid - rot @ half, mid + rot @ half


@pytest.mark.parametrize("case", ["far_from_centroid", "shorter_than_the_median"])
def test_merge_collinear_merges_nearly_collinear_duplicates(case):
    if case == "far_from_centroid":
        a, b = np.array([100.0, 0.0]), np.array([110.0, 0.0])
        c, d = _rotated_copy(a, b, 0.8 * TOL)
        p0 = np.array([a, c, [-100.0, 0.0], [-100.0, 5.0]])
        p1 = np.array([b, d, [-90.0, 0.0], [-90.0, 5.0]])
    else:  # near the centroid, but turned by 0.016 rad x median length 20 mm
        a, b = np.array([0.0, 0.0]), np.array([1.0, 0.0])
        c, d = _rotated_copy(a, b, 0.8 * TOL)
        p0 = np.array([a, c, [-10.0, 8.0], [-10.0, -8.0], [-10.0, 16.0]])
        p1 = np.array([b, d, [10.0, 8.0], [10.0, -8.0], [10.0, 16.0]])
    assert _duplicates(p0, p1, 0, 1, TOL)
    _check_merge(p0, p1, TOL)
