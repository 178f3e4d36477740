"""The 8-bit preview tone map of ``render`` outputs.

The ``.npy`` files hold linear radiance; the ``.png`` preview is, per image:

1. exposure E = the 99.5th percentile of the image's finite positive values (1.0 when
   there are none), unless a fixed exposure is given;
2. v = clip(L / E, 0, 1): everything at or above the exposure is white;
3. the sRGB transfer curve (IEC 61966-2-1): 12.92 v for v <= 0.0031308, else
   1.055 v^(1/2.4) - 0.055;
4. round(255 * value) as 8-bit grey.

E is stored in the PNG's text chunk ``scratchfab.exposure`` so the preview can be
turned back into approximate radiance.
"""

from __future__ import annotations

import numpy as np

from scratchfab.design.images import linear_to_srgb

#: Percentile of the positive pixels that maps to white.
WHITE_PERCENTILE = 99.5


def exposure(image: np.ndarray) -> float:
    """The exposure E of step 1 for ``image``."""
    values = np.asarray(image, dtype=np.float64)
    positive = values[np.isfinite(values) & (values > 0)]
    if positive.size == 0:
        return 1.0
    return float(np.percentile(positive, WHITE_PERCENTILE))


def tone_map(image: np.ndarray, exposure_value: float | None = None) -> tuple[np.ndarray, float]:
    """8-bit preview of a linear image (non-finite pixels become black).

    Args:
        image: (H, W) linear radiance.
        exposure_value: The radiance shown white (default: step 1's percentile).

    Returns:
        (uint8 (H, W), the exposure used).

    Raises:
        ValueError: ``exposure_value`` is not a finite number > 0.
    """
    e = exposure(image) if exposure_value is None else float(exposure_value)
    if not (np.isfinite(e) and e > 0):
        raise ValueError(f"exposure_value: expected a finite number > 0, got {exposure_value}")
    values = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    encoded = linear_to_srgb(values / e)
    return np.round(255 * encoded).astype(np.uint8), e
