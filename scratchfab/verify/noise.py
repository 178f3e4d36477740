"""What a verify render's Monte Carlo noise does to its rho, in words a maker acts on.

:func:`scratchfab.metrics.noise_effect` estimates, from the renders' own batch spread,
the rho a noise-free render would reach; this module turns the figures ``metrics.json``
records for a view (``rho``, ``rho_noise_free``, ``noise_to_signal``, ``noise``, ``spp``,
``seconds``, ``seconds_per_spp``, ``diff_noise_share``, ``noise_knee_spp``) into advice:
whether the noise explains a failed gate, and the sample count that would end it (and
about how long that takes). It imports no renderer, so the report uses it.

The stratified sampler's noise falls faster than 1 / spp once its strata resolve the
scratches (:func:`knee_spp`). Measured on the demo (from 264 spp) and a maker's 100 x 80
mm board (from 70 spp), aiming at the noise that 4 to 16 times the samples measured: the
count 1 / spp names was 1.2 to 4.7 times the one that measured it, the knee's model's
0.87 to 1.03 times (on the tests' coarse 32 px board up to 1.3 times, the noise falling
faster still). Without a knee (a metrics.json from before, or too few samples to show
one: two batches of 8 samples seldom do) the advice takes 1 / spp and asks for more.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from scratchfab.console import duration_text
from scratchfab.metrics import NOISE_RHO_LOSS, NoiseEffect

#: Without a noise-free estimate (the render is mostly noise), the named sample count is
#: (at least) this many times the one taken.
NOISY_SPP_FACTOR = 16
#: A difference map at least this much noise (a share of its squared size) says so ...
NOISY_MAP_SHARE = 0.25
#: ... and names the sample count that brings the share under this.
QUIET_MAP_SHARE = 0.2


def knee_spp(spp: int, variance: float, unstratified: float) -> float | None:
    """The sample count past which a render's noise falls faster than 1 / spp.

    The multi-jitter sampler stratifies each pixel: while its strata are wider than the
    scratches' lobes a pixel's noise falls as unstratified samples' would, as 1 / spp;
    once they resolve the lobes it falls faster. The noise's variance at n spp is taken
    as V(n) = U(n) / (1 + n / knee), U(n) the variance that n unstratified samples
    leave (their own spread over n), so one render, which measures both V and U, fixes
    the knee. Fitted on the demo and a maker's 100 x 80 mm board, 16 to 16560 spp: the
    fall steepens from 1 / spp^1.05 to 1 / spp^1.7 near 4096 spp, as this does.

    Args:
        spp: The samples per pixel taken.
        variance: The render's noise variance (summed over the pixels).
        unstratified: What ``spp`` unstratified samples would leave (summed alike).

    Returns:
        The knee in samples per pixel; None where the render shows no gain over 1 / spp.
    """
    if not (unstratified > 0 and 0 < variance < unstratified):
        return None
    gain = variance / unstratified
    return spp * gain / (1 - gain)


def variance_ratio(spp: int, more: float, knee: float | None) -> float:
    """How many times less noise variance ``more`` spp leave than ``spp`` (the knee's model)."""
    slope = 0.0 if knee is None else 1.0 / knee
    return more * (1 + more * slope) / (spp * (1 + spp * slope))


def spp_for(spp: int, factor: float, knee: float | None) -> float:
    """The samples per pixel that leave ``1 / factor`` of ``spp``'s noise variance."""
    goal = factor * spp * (1 + spp / knee) if knee is not None else factor * spp
    if knee is None:
        return goal
    return knee / 2 * (math.sqrt(1 + 4 * goal / knee) - 1)


def more_spp(spp: float) -> int:
    """``spp`` rounded up to a count a maker types, at most an eighth above it.

    Eight steps an octave: 1024, 1152, 1280, ..., 1920, 2048.
    """
    need = max(1.0, spp * (1 - 1e-9))
    step = 1 << max(0, math.floor(math.log2(need)) - 3)
    return step * math.ceil(need / step)


def render_seconds(entry: Mapping[str, Any], spp: int) -> float | None:
    """About how long a view's render would take with ``spp`` samples per pixel.

    Its own time, plus the added samples at ``seconds_per_spp`` (what a sample per pixel
    cost once compiled); a metrics.json without that scales the whole time, compiling
    included. None where the entry keeps no time.
    """
    seconds, taken, per_spp = entry.get("seconds"), entry.get("spp"), entry.get("seconds_per_spp")
    if not isinstance(seconds, float) or not taken:
        return None
    if isinstance(per_spp, float) and math.isfinite(per_spp) and per_spp >= 0:
        return seconds + max(0, spp - taken) * per_spp
    return seconds * spp / taken


def _knee(entry: Mapping[str, Any]) -> float | None:
    """The view's ``noise_knee_spp`` (None where missing, or not a number above 0)."""
    knee = entry.get("noise_knee_spp")
    if not isinstance(knee, int | float) or isinstance(knee, bool):
        return None
    return float(knee) if math.isfinite(knee) and knee > 0 else None


def _effect(entry: Mapping[str, Any]) -> NoiseEffect | None:
    """The :class:`NoiseEffect` a metrics.json view entry records (None: not measured)."""
    rho, ratio = entry.get("rho"), entry.get("noise_to_signal")
    if rho is None or "rho_noise_free" not in entry:
        return None
    free = entry["rho_noise_free"]
    if free is None or ratio is None:
        return NoiseEffect(rho, None, 0.0, 0.0)
    return NoiseEffect(rho, free, 1.0, ratio)


def noise_explains(entry: Mapping[str, Any], min_rho: float | None) -> bool:
    """Whether a view's rho falls short of ``min_rho`` only for the render's noise."""
    effect = _effect(entry)
    if effect is None or min_rho is None or not effect.rho < min_rho:
        return False
    return effect.rho_free is None or effect.rho_free > min_rho


def noise_advice(entry: Mapping[str, Any], min_rho: float | None, spp_setting: str) -> str:
    """What the render's sampling noise does to a view's rho, and the spp that ends it.

    Args:
        entry: The view's entry in ``metrics.json``.
        min_rho: The gate, or None.
        spp_setting: How the user sets the sample count (``--spp``, ``[verify] spp =``).

    Returns:
        One clause (no leading capital, no full stop), or "" where the noise costs rho
        less than :data:`~scratchfab.metrics.NOISE_RHO_LOSS` (or was not measured).
    """
    effect = _effect(entry)
    spp, noise = entry.get("spp"), entry.get("noise")
    if effect is None or not spp or noise is None:
        return ""
    free = effect.rho_free
    knee = _knee(entry)
    if free is None:
        more = more_spp(spp * NOISY_SPP_FACTOR)
    else:
        # Where the gate fails for noise alone, half the way from the gate to the
        # noise-free rho is left to the noise, so the named count passes it.
        loss = NOISE_RHO_LOSS
        if min_rho is not None and effect.rho < min_rho < free:
            loss = min(loss, (free - min_rho) / 2)
        factor = effect.variance_factor(loss) or 1.0
        if factor <= 1.0:
            return ""
        more = more_spp(spp_for(spp, factor, knee))
    ratio = variance_ratio(spp, more, knee)
    took = render_seconds(entry, more)
    later = f", about {duration_text(took)} a view" if took is not None else ""
    then = f"{spp_setting} {more} brings the noise to about {100 * noise / math.sqrt(ratio):.1f} %"
    noisy = f"the render's sampling noise ({100 * noise:.1f} %)"
    if free is None:
        return (
            f"{noisy} outweighs the picture, so rho says little; {then}{later} (at least: "
            "the noise hides how far)"
        )
    expect = effect.rho_at(ratio)
    at = f"{then} and rho to about {expect:.3f}{later}" if expect is not None else then
    if noise_explains(entry, min_rho):
        return f"{noisy} explains it: a noise-free render would reach rho about {free:.3f}; {at}"
    return f"{noisy} costs rho about {free - effect.rho:.3f} (noise-free about {free:.3f}); {at}"


def diff_noise_advice(entry: Mapping[str, Any], spp_setting: str) -> str:
    """A line for a difference map that is in good part sampling noise ("" otherwise).

    The noise's part of the map's squared size falls with its variance while the board's
    stays: at k times less variance a share p becomes (p / k) / (p / k + 1 - p).
    """
    share, spp = entry.get("diff_noise_share"), entry.get("spp")
    if not isinstance(share, int | float) or not share >= NOISY_MAP_SHARE or not spp:
        return ""
    quiet = QUIET_MAP_SHARE
    if share < 1:
        factor = share * (1 - quiet) / (quiet * (1 - share))
        more = more_spp(spp_for(spp, factor, _knee(entry)))
    else:
        more = more_spp(spp * NOISY_SPP_FACTOR)
    then = f"brings it under {100 * quiet:.0f} %" if share < 1 else "at least"
    return (
        f"{'mostly ' if share >= 0.5 else ''}sampling noise: about {100 * share:.0f} % of "
        f"these differences is the render's noise, not the board; {spp_setting} {more} {then}"
    )
