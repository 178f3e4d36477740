"""The design stage's header line counts its views in words a reader expects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scratchfab.design.stage import run_design


def _design(tmp_path: Path, n_views: int) -> Path:
    """A 40 x 40 mm design with ``n_views`` views spread left to right, 60 scratches."""
    picture = np.zeros((24, 24), np.uint8)
    picture[:, :12] = 255
    Image.fromarray(picture).save(tmp_path / "a.png")
    views = "".join(
        f'[[views]]\nname = "v{i}"\ntarget = "a.png"\nazimuth_deg = {az}\n'
        'elevation_deg = 0.0\ndistance_mm = 500.0\nfov_deg = "auto"\nresolution = [16, 16]\n'
        for i, az in enumerate(np.linspace(-22.0, 22.0, n_views) if n_views > 1 else [0.0])
    )
    path = tmp_path / "scene.toml"
    path.write_text(
        "[board]\nwidth_mm = 40.0\nheight_mm = 40.0\nmargin_mm = 1.0\n"
        "[light]\nposition_mm = [0.0, 187.3, 463.6]\n"
        "[scratch]\ncount = 60\nmin_length_mm = 1.0\nmax_length_mm = 5.0\n" + views
    )
    return path


@pytest.mark.parametrize(("n_views", "words"), [(1, "1 view,"), (2, "2 views,")])
def test_header_says_view_for_one_and_views_for_more(tmp_path, n_views, words):
    lines: list[str] = []
    res = run_design(_design(tmp_path, n_views), tmp_path / "job", progress=lines.append)
    assert len(res.design.views) == n_views
    header = lines[0]
    assert header == f"design: {words} 60 scratches on a 40 x 40 mm board"
