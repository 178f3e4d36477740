"""Streaming throughput: character counting vs simple send-response on the GRBL emulator.

The emulator models the serial line (10 bits per byte at 115200 baud, both directions), an
optional USB latency per direction, and motion as GRBL's planner runs it (the feeds,
$110-$112 rates, $120-$122 accelerations, corners by $11; time_scale 1, i.e. real time).
Jobs are strokes in the exporter's format (G0 Z / G0 XY / G1 Z / G1 XY / G0 Z):

- ``short``: 0.1 mm strokes, 0.05 mm Z hops, F5000, $110-$112 = 5000 mm/min and
  $120-$122 = 1e5 mm/s^2: each move takes about a millisecond, so the link, not the
  machine, limits the speed (at GRBL's default 10 mm/s^2 each move would take ~0.1 s);
- ``engrave``: 2 mm strokes at F800, Z at 500 mm/min, GRBL's default accelerations:
  motion-bound.

Prints JSON (lines per second per protocol and the counting/simple ratio). The goal is judged
with 1 ms of USB latency per direction (a CH340 is about that, an FTDI at its default latency
timer up to 16 ms): over an ideal zero-latency link send-response costs only the answer's
4 bytes and the host's turnaround per line, which caps the ratio near 1.7 at 115200 baud.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from scratchfab.machine.sender import Streamer, StreamOptions, open_port
from scratchfab.machine.sender_journal import Journal
from scratchfab.machine.sender_program import load_program


def write_job(path: Path, strokes: int, length_mm: float, hop_mm: float, feed: float) -> None:
    rng = np.random.default_rng(3)
    lines = ["G21 G90 G17 G94", f"G0 Z{hop_mm:g}"]
    x, y = 0.0, 0.0
    for _ in range(strokes):
        x, y = x + rng.uniform(-0.2, 0.2), y + rng.uniform(-0.2, 0.2)
        angle = rng.uniform(0, 2 * np.pi)
        u, v = length_mm * np.cos(angle), length_mm * np.sin(angle)
        lines += [
            f"G0 Z{hop_mm:g}",
            f"G0 X{x:.3f} Y{y:.3f}",
            f"G1 Z-0.02 F{feed:g}",
            f"G1 X{x + u:.3f} Y{y + v:.3f} F{feed:g}",
            f"G0 Z{hop_mm:g}",
        ]
    path.write_text("\n".join(lines) + "\n")


def run(job: Path, protocol: str, url: str) -> dict[str, float]:
    prog = load_program(job)
    port = open_port(url, 115200)
    try:
        streamer = Streamer(port, StreamOptions(protocol=protocol, banner_timeout=0.5))
        streamer.connect()
        with tempfile.TemporaryDirectory() as tmp:
            journal = Journal(Path(tmp) / "j.jsonl").open()
            t0 = time.perf_counter()
            streamer.stream(prog, journal)
            elapsed = time.perf_counter() - t0
            journal.close()
    finally:
        port.close()
    sim = port.sim
    return {
        "lines": len(prog.blocks),
        "seconds": round(elapsed, 3),
        "lines_per_s": round(len(prog.blocks) / elapsed, 1),
        "rx_overruns": sim.overruns,
    }


SCENARIOS = {
    # name: (stroke length mm, Z hop mm, feed mm/min, $110-$112 mm/min, $120-$122 mm/s^2)
    "short": (0.1, 0.05, 5000.0, 5000.0, 1e5),
    "engrave": (2.0, 0.5, 800.0, 500.0, 10.0),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "strokes", nargs="?", type=int, default=200, help="strokes of the short job (200)"
    )
    strokes = parser.parse_args().strokes
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (length, hop, feed, rate, accel) in SCENARIOS.items():
            job = Path(tmp) / f"{name}.gcode"
            write_job(job, strokes if name == "short" else 10, length, hop, feed)
            for latency_ms in (0.0, 1.0) if name == "short" else (1.0,):
                url = (
                    f"grblsim://?baud=115200&time_scale=1&latency={latency_ms / 1000}"
                    f"&$110={rate}&$111={rate}&$112={rate}&$120={accel}&$121={accel}&$122={accel}"
                )
                row = {p: run(job, p, url) for p in ("counting", "simple")}
                speedup = row["counting"]["lines_per_s"] / row["simple"]["lines_per_s"]
                results[f"{name}_usb_latency_{latency_ms:g}ms"] = {
                    "stroke_mm": length,
                    "feed_mm_min": feed,
                    "max_rate_mm_min": rate,
                    "acceleration_mm_s2": accel,
                    **row,
                    "speedup": round(speedup, 2),
                }
    print(
        json.dumps(
            {
                "benchmark": "stream",
                "baud": 115200,
                "results": results,
                "goal": "counting >= 2x simple lines/s on short strokes (1 ms USB latency)",
                "goal_met": results["short_usb_latency_1ms"]["speedup"] >= 2.0,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
