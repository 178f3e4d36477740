from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import CHROMIUM, check_report_in_chromium
from PIL import Image

from scratchfab.pipeline.manifest import Manifest, fingerprint
from scratchfab.pipeline.report import write_report


def _png(path: Path, seed: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 255, (16, 16), dtype=np.uint8)).save(path)


def fake_job(root: Path) -> Path:
    job = root / "job"
    for i, name in enumerate(("left", "right")):
        _png(job / "design" / "targets" / f"{name}.png", i)
        _png(job / "optimize" / "renders" / f"{name}.png", 10 + i)
        _png(job / "verify" / f"{name}.png", 20 + i)
    frames = [Image.fromarray(np.full((8, 8), v, np.uint8)) for v in (0, 128, 255)]
    frames[0].save(job / "verify" / "sweep.gif", save_all=True, append_images=frames[1:])
    metrics = {
        "views": {
            "left": {
                "rho": 0.91234,
                "psnr": 21.5,
                "rel_l2": 0.0123,
                "spp": 64,
                "seconds": 2.0,
                "crosstalk": {"right": 0.0456},
            },
            "right": {
                "rho": 0.8765,
                "psnr": 19.25,
                "rel_l2": 0.0099,
                "spp": 64,
                "seconds": 2.1,
                "crosstalk": {"left": -0.0123},
            },
        }
    }
    (job / "verify" / "metrics.json").write_text(json.dumps(metrics))
    return job


def test_report_is_self_contained_and_shows_metrics(tmp_path):
    job = fake_job(tmp_path)
    page = write_report(job).read_text()
    # No external resources: every src is a data URI.
    srcs = re.findall(r'src="([^"]*)"', page)
    assert len(srcs) == 7 and all(s.startswith("data:image/") for s in srcs)
    values = dict(re.findall(r'data-metric="([^"]+)" data-value="([^"]+)"', page))
    assert float(values["left.rho"]) == 0.91234
    assert float(values["left.crosstalk.right"]) == 0.0456
    assert float(values["right.crosstalk.left"]) == -0.0123


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)"
)
def test_report_images_decode_in_headless_chromium(tmp_path):
    job = fake_job(tmp_path)
    shown = check_report_in_chromium(write_report(job), tmp_path / "profile")
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    for view, entry in metrics["views"].items():
        assert float(shown[f"{view}.rho"]) == pytest.approx(entry["rho"], abs=5e-4)
        assert float(shown[f"{view}.psnr"]) == pytest.approx(entry["psnr"], abs=5e-3)


def test_manifest_detects_changes_and_touches(tmp_path):
    src = tmp_path / "cat.png"
    _png(src, 1)
    made = tmp_path / "job" / "design" / "scratches.csv"
    made.parent.mkdir(parents=True)
    made.write_text("x0,y0,x1,y1\n")
    manifest = Manifest.load(tmp_path / "job")
    inputs = fingerprint([made], [src], {"seed": 1})
    assert not manifest.is_current("design", inputs)
    manifest.record("design", inputs, ["design/scratches.csv"], 0.1)
    again = Manifest.load(tmp_path / "job")
    assert again.is_current("design", fingerprint([made], [src], {"seed": 1}))
    assert not again.is_current("design", fingerprint([made], [src], {"seed": 2}))
    made.write_text("x0,y0,x1,y1\n0,0,1,1\n")
    assert not again.is_current("design", fingerprint([made], [src], {"seed": 1}))
    made.write_text("x0,y0,x1,y1\n")
    import os

    st = src.stat()
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # touched, same bytes
    assert not again.is_current("design", fingerprint([made], [src], {"seed": 1}))
