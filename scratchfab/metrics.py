"""Quality measures that compare boards (SPEC section 7).

All functions take linear images of one view's camera, shape (H, W); a target's NaN
pixels lie off the board and are ignored.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from decimal import ROUND_FLOOR, Decimal
from typing import Any

import numpy as np


def board_mask(target: np.ndarray, *others: np.ndarray) -> np.ndarray:
    """Pixels where ``target`` and every array in ``others`` are finite (the board)."""
    mask = np.isfinite(target)
    for other in others:
        mask &= np.isfinite(other)
    return mask


def exposure(render: np.ndarray, target: np.ndarray) -> float:
    """The scale s minimising |s R - T|^2 over the board pixels (0 for a black render)."""
    mask = board_mask(target, render)
    r = render[mask].astype(np.float64)
    t = target[mask].astype(np.float64)
    rr = float(r @ r)
    return float(r @ t) / rr if rr > 0 else 0.0


def psnr(render: np.ndarray, target: np.ndarray) -> float:
    """PSNR in dB of the exposed render ``s R`` against ``T`` (peak 1)."""
    diff, _ = exposed_difference(render, target)
    err = diff[np.isfinite(diff)]
    mse = float(np.mean(err * err)) if err.size else 0.0
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def exposed_difference(render: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
    """The signed error ``s R - T`` that :func:`psnr` squares, and the exposure ``s``.

    Positive where the exposed render is brighter than the target; NaN off the board
    (where :func:`board_mask` leaves a pixel out of every measure).
    """
    s = exposure(render, target)
    mask = board_mask(target, render)
    diff = np.full(target.shape, np.nan)
    diff[mask] = s * render[mask].astype(np.float64) - target[mask].astype(np.float64)
    return diff, s


def pearson(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Pearson correlation of two images over ``mask`` (0 when either is constant)."""
    if mask is None:
        mask = board_mask(a, b)
    x = a[mask].astype(np.float64)
    y = b[mask].astype(np.float64)
    if x.size < 2:
        return 0.0
    x = x - x.mean()
    y = y - y.mean()
    den = math.sqrt(float(x @ x) * float(y @ y))
    return float(x @ y) / den if den > 0 else 0.0


#: The rho that Monte Carlo noise may cost before verify names a higher sample count.
NOISE_RHO_LOSS = 0.005


@dataclass(frozen=True)
class NoiseEffect:
    """How a render's Monte Carlo noise bends its rho_kk, estimated from one render.

    The render is R = R_inf + N with zero-mean noise N of known per-pixel variance. Over
    the board pixels the noise leaves the covariance with the target as it is but adds
    its variance to the render's, so rho = rho_inf sqrt(signal / (signal + noise)),
    with ``noise`` the summed pixel variance and ``signal`` the render's summed squared
    deviation less it. More samples divide the noise variance by a factor
    (:func:`scratchfab.verify.noise.variance_ratio` tells it for a sample count).

    Attributes:
        rho: The measured rho.
        rho_free: Estimated rho of a noise-free render (None where the noise outweighs
            the picture's own contrast and no estimate holds).
        signal: Summed squared deviation of the noise-free render over the board.
        noise: Summed noise variance over the board (centred as the deviation is).
    """

    rho: float
    rho_free: float | None
    signal: float
    noise: float

    def rho_at(self, factor: float) -> float | None:
        """The rho expected with ``factor`` times less noise variance (None without an estimate)."""
        if self.rho_free is None:
            return None
        return self.rho_free * math.sqrt(self.signal / (self.signal + self.noise / factor))

    def variance_factor(self, loss: float = NOISE_RHO_LOSS) -> float | None:
        """How many times less noise variance makes the noise cost rho at most ``loss``.

        1 when it already does; None without an estimate.
        """
        if self.rho_free is None:
            return None
        if abs(self.rho_free) <= loss or self.noise <= 0:
            return 1.0
        q = 1.0 - loss / abs(self.rho_free)
        allowed = self.signal * (1.0 / (q * q) - 1.0)
        return max(1.0, self.noise / allowed)


def noise_effect(render: np.ndarray, target: np.ndarray, variance: np.ndarray) -> NoiseEffect:
    """The :class:`NoiseEffect` of a render whose pixels have the noise ``variance``."""
    mask = board_mask(target, render) & np.isfinite(variance)
    r = render[mask].astype(np.float64)
    rho = pearson(render, target, mask)
    n = r.size
    if n < 2:
        return NoiseEffect(rho, rho, 0.0, 0.0)
    spread = float(np.sum((r - r.mean()) ** 2))
    noise = float(np.sum(variance[mask])) * (n - 1) / n  # what centring leaves of it
    signal = spread - noise
    if not signal > 0:
        return NoiseEffect(rho, None, 0.0, noise)
    free = max(-1.0, min(1.0, rho * math.sqrt(spread / signal)))
    return NoiseEffect(rho, free, signal, noise)


def noise_share(render: np.ndarray, target: np.ndarray, variance: np.ndarray) -> float:
    """Share of the exposed difference ``s R - T``'s squared size that is render noise.

    With R = R_0 + N over the board, the exposure fitted to R shrinks as the noise adds
    V (the summed pixel variance) to |R|^2, and |s R - T|^2 = |T|^2 - (R T)^2 / |R|^2
    exceeds the noise-free difference's by (R T)^2 V / (|R|^2 (|R|^2 - V)), that is
    s^2 V |R|^2 / (|R|^2 - V): s^2 V alone (the noise of the exposed render) leaves out
    what the noise does to s, and undercounts a noisy render's share (16 spp on the demo:
    0.6 against 0.98 measured). This is that excess over the whole (1 where the noise is
    all of |R|^2; 0 for a render equal to the target only where no noise is either; NaN
    without board pixels).
    """
    diff, s = exposed_difference(render, target)
    ok = np.isfinite(diff) & np.isfinite(variance)
    if not ok.any():
        return math.nan
    total = float(np.sum(diff[ok] ** 2))
    noise = float(np.sum(variance[ok]))
    size = float(np.sum(np.asarray(render, np.float64)[ok] ** 2))
    if not size > noise:
        return 1.0 if noise > 0 else 0.0
    excess = s * s * noise * size / (size - noise)
    return min(1.0, excess / total) if total > 0 else 0.0


def quality_report(
    renders: Mapping[str, np.ndarray],
    targets: Mapping[str, np.ndarray],
    cross: Mapping[tuple[str, str], np.ndarray] | None = None,
) -> dict[str, Any]:
    """Exposure, PSNR, rho_kk and crosstalk x_kj for every view.

    Args:
        renders: R_k per view name.
        targets: T_k per view name (NaN off the board).
        cross: T_j->k keyed by (k, j): image j as view k's camera sees it. Without it,
            only the diagonal is reported.

    Returns:
        ``{"views": {k: {"exposure", "psnr", "rho", "rho_to": {j: rho_kj},
        "crosstalk": {j: x_kj}}}, "names": [...], "crosstalk_matrix": [[x_kj]]}`` with
        NaN on the matrix diagonal (crosstalk is defined for j != k only).
    """
    names = list(renders)
    views: dict[str, Any] = {}
    for k in names:
        render, target = renders[k], targets[k]
        mask = board_mask(target, render)
        entry: dict[str, Any] = {
            "exposure": exposure(render, target),
            "psnr": psnr(render, target),
            "rho": pearson(render, target, mask),
            "rho_to": {},
            "crosstalk": {},
        }
        for j in names:
            if j == k or cross is None or (k, j) not in cross:
                continue
            other = cross[(k, j)]
            m = mask & np.isfinite(other)
            rho_kj = pearson(render, other, m)
            entry["rho_to"][j] = rho_kj
            entry["crosstalk"][j] = rho_kj - pearson(target, other, m)
        views[k] = entry
    matrix = [[views[k]["crosstalk"].get(j, math.nan) for j in names] for k in names]
    return {"names": names, "views": views, "crosstalk_matrix": matrix}


#: What a crosstalk x_kj measures, after "j's picture showing in view k" (SPEC: rho_kj
#: less the correlation the two target pictures have anyway).
CROSSTALK_MEANING = (
    "beyond what the two pictures share; 0 = none, 1 = fully, below 0 = less than they share"
)


def rho_text(rho: float, min_rho: float | None = None) -> str:
    """``rho`` rounded down to 3 decimals, or to as many as ``min_rho`` is written with.

    One rule for every line that shows a rho next to a gate: rounded down, a rho below
    ``min_rho`` never reads as reaching it (0.7996 below 0.8 reads 0.799; 0.99894 below
    0.99999 reads 0.99894, not 0.999). Digits come from the shortest form of the number,
    so a rho written 0.99894 is not floored to 0.99893 by binary rounding.
    """
    decimals = 3
    if min_rho is not None:
        exponent = Decimal(repr(float(min_rho))).normalize().as_tuple().exponent
        decimals = min(max(3, -int(exponent)), 9)
    step = Decimal(1).scaleb(-decimals)
    return str(Decimal(repr(float(rho))).quantize(step, rounding=ROUND_FLOOR))
