from __future__ import annotations

import numpy as np
from gcode_interp import cuts, interpret
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.export.gcode import gcode_lines
from scratchfab.machine.profile import profile_from_mapping
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath import OrderOptions, plan_toolpath

finite = {"allow_nan": False, "allow_infinity": False}


@st.composite
def profiles(draw):
    lo = [draw(st.floats(-400, 100, **finite)) for _ in range(3)]
    span = [draw(st.floats(20, 400, **finite)) for _ in range(3)]
    env = {axis: [lo[i], lo[i] + span[i]] for i, axis in enumerate(("x_mm", "y_mm", "z_mm"))}
    start = [draw(st.floats(lo[i], lo[i] + span[i], **finite)) for i in range(2)]
    z_safe = draw(st.floats(lo[2] + 1, lo[2] + span[2], **finite))
    z_cut = draw(st.floats(lo[2], z_safe - 0.5, **finite))
    mode = draw(st.sampled_from(["z", "servo", "spindle"]))
    table = {
        "name": "random",
        "start_mm": start,
        "envelope": env,
        "board": {
            "origin": draw(
                st.sampled_from(
                    ["lower-left", "lower-right", "upper-left", "upper-right", "center"]
                )
            ),
            "offset_mm": [
                draw(st.floats(lo[0] - 20, lo[0] + span[0] + 20, **finite)),
                draw(st.floats(lo[1] - 20, lo[1] + span[1] + 20, **finite)),
            ],
            "rotation_deg": draw(st.sampled_from([0, 90, 180, 270])),
        },
        "z": {"safe_mm": z_safe, "engrave_mm": z_cut},
        "feeds": {"engrave_mm_min": 500.0, "plunge_mm_min": 100.0},
        "motion": {"max_rate_mm_min": [3000.0, 3000.0, 800.0]},
        "tool": {"width_mm": 0.1, "depth_mm": 0.01, "min_length_mm": draw(st.floats(0, 3))},
        "tool_control": {"mode": mode, "dwell_s": draw(st.sampled_from([0.0, 0.2]))},
        "gcode": {"decimals": draw(st.integers(0, 5))},
    }
    # the rounding of the drawn decimals within the tool's tolerance, as a profile must be
    table["tool"]["tolerance_mm"] = max(0.01, 0.5 * 10.0 ** -table["gcode"]["decimals"])
    if draw(st.booleans()):
        table["feeds"]["travel_mm_min"] = 2000.0
    try:
        return profile_from_mapping(table, "<random>")
    except ConfigError as exc:
        # Only Z heights that the decimals cannot hold apart or inside the envelope.
        assert "gcode.decimals" in str(exc) and "z." in str(exc) and mode != "servo"
        reject()


@st.composite
def boards(draw):
    w = draw(st.floats(5, 120, **finite))
    h = draw(st.floats(5, 120, **finite))
    n = draw(st.integers(0, 40))
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    p0 = rng.uniform([-w / 2, -h / 2], [w / 2, h / 2], (n, 2))
    p1 = rng.uniform([-w / 2, -h / 2], [w / 2, h / 2], (n, 2))
    if n and draw(st.booleans()):
        p1[: n // 2] = p0[: n // 2] + rng.normal(0, 0.3, (n // 2, 2))
    same = np.all(p0 == p1, axis=1)
    p1[same] += 0.1
    p1 = np.clip(p1, [-w / 2, -h / 2], [w / 2, h / 2])
    board = Board(width_mm=w, height_mm=h, margin_mm=0.0)
    return board, ScratchSet.from_arrays(p0, p1, 0.1, 0.01)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(profile=profiles(), job=boards())
def test_gcode_stays_in_envelope_and_sets_feed_first(profile, job):
    board, scratches = job
    try:
        tp = plan_toolpath(scratches, board, profile, options=OrderOptions(passes=4))
    except ScratchfabError as exc:
        assert "outside the envelope" in str(exc)
        # Independently: the board's corners, mapped as the strokes are, span a box whose
        # overlap with the envelope (less the rounding slack) has no area.
        w, h = board.width_mm / 2, board.height_mm / 2
        corners = profile.board_to_machine(
            np.array([[-w, -h], [w, -h], [w, h], [-w, h]]), (board.width_mm, board.height_mm)
        )
        slack = 0.5 * 10.0 ** (-profile.gcode.decimals)
        env = profile.envelope
        overlap = [
            min(corners[:, k].max(), hi - slack) - max(corners[:, k].min(), lo + slack)
            for k, (lo, hi) in enumerate((env.x_mm, env.y_mm))
        ]
        assert min(overlap) <= 1e-9, overlap
        return
    lines = gcode_lines(tp)
    text = "\n".join(lines) + "\n"
    run = interpret(text, profile.gcode.max_line_length)  # raises on G1 before F (error 22)
    env = profile.envelope
    for mv in run.moves:
        for p in (mv.start, mv.end):
            assert env.x_mm[0] <= p[0] <= env.x_mm[1]
            assert env.y_mm[0] <= p[1] <= env.y_mm[1]
            if profile.tool_control.mode != "servo":
                assert env.z_mm[0] <= p[2] <= env.z_mm[1]
    mode = profile.tool_control.mode
    dec = profile.gcode.decimals
    safe, cut = round(profile.z.safe_mm, dec), round(profile.z.engrave_mm, dec)
    thr = None if mode == "servo" else 0.5 * (safe + cut)
    cutting, _ = cuts(run, thr)
    assert len(cutting) == len(tp)
