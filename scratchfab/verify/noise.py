"""What a verify render's Monte Carlo noise does to its rho, in words a maker acts on.

:func:`scratchfab.metrics.noise_effect` estimates, from the renders' own batch spread,
the rho a noise-free render would reach; this module turns the figures ``metrics.json``
records for a view (``rho``, ``rho_noise_free``, ``noise_to_signal``, ``noise``, ``spp``,
``seconds``, ``seconds_per_spp``, ``diff_noise_share``, ``noise_knee_spp``,
``noise_equivalent_spp``) into advice: whether the noise explains a failed gate, and the
sample count that would end it (and about how long that takes). It imports no renderer,
so the report uses it.

The stratified sampler's noise falls faster than 1 / spp once its strata resolve the
scratches (:func:`knee_spp`). Measured on the demo (from 264 spp) and a maker's 100 x 80
mm board (from 70 spp), aiming at the noise that 4 to 16 times the samples measured: the
count 1 / spp names was 1.2 to 4.7 times the one that measured it, the knee's model's
0.87 to 1.03 times (on the tests' coarse 32 px board up to 1.3 times, the noise falling
faster still); read from the gain 2.5 standard errors up (:data:`KNEE_ERRORS`) and over
the little the strata remove at any count (:data:`GAIN_FLOOR`), 0.9 to 1.5 times on the
demo from 256 spp, and on coarse boards, whose noise falls as 1 / spp for thousands of
samples, no knee where a render does not show one. Below 64 spp one render does not fix
the knee (:data:`MIN_KNEE_BATCH`):
on the demo the knee read from 32 spp named 0.6 to 0.9 times the count needed, and from
16 spp half the renders showed none, the others one at random (0.5 to 2.5 times); the
advice takes 1 / spp there, as for a metrics.json from before the knee, and names 1.4 to
3.7 times the count (about 2 times for the demo's own gate). A render whose noise
target added batches counts as two batches of fewer samples (:func:`render_knee`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from scratchfab.console import duration_text
from scratchfab.metrics import NOISE_RHO_LOSS, NoiseEffect

#: Without a noise-free estimate (the render is mostly noise), the named sample count is
#: (at least) this many times the one taken.
NOISY_SPP_FACTOR = 16
#: A difference map at least this much noise (a share of its squared size) says so ...
NOISY_MAP_SHARE = 0.25
#: ... and names the sample count that brings the share under this.
QUIET_MAP_SHARE = 0.2


#: The knee is read from batches of at least this many samples: the multi-jitter sampler's
#: smaller grids gain erratically (on the demo, batches of 8 samples not at all, of 16 more
#: than the knee that holds past them says: the count named 0.6 to 0.9 times the one needed).
MIN_KNEE_BATCH = 32
#: The knee is read from the gain this many standard errors above the one measured (a gain
#: within the render's own noise of :data:`GAIN_FLOOR` says 1 / spp).
KNEE_ERRORS = 2.5
#: The gain that tells no knee: the sampler's strata remove some of the noise at any count
#: (the parts of a pixel that vary smoothly: 0.93 to 0.95 of it is left from 64 spp on, on
#: the demo and on a 32 px board of 200 scratches, besides the knee's own fall), so a gain
#: down to this is no sign of a knee. Read from a gain of 1 (and the pixels' spread alone
#: for its error, at two of them), that board's knee at 64 to 256 spp came out at 0.1 to
#: 0.4 times the 7000 spp its noise falls by from 1000 spp on: the count named for the
#: noise that 8 to 64 times the samples measured fell to 0.45 times the one needed, for the
#: 10 to 40 % of the renders that read one. With this floor and :data:`KNEE_ERRORS`, on it,
#: a second such board, the demo and the tests' 12 mm board (whose knee is 150 to 300 spp)
#: the count named was at least 0.85 times the one needed (0.35 before; 1 / spp names as
#: little from the same renders: their own spread). In the mean it named 1.3 to 1.7 times
#: the count from 256 spp (1.1 to 1.5 before), 1.7 to 2.2 from 128 (1.2 to 1.6), and from
#: 64 spp 1.5 on the coarse boards, 3.2 on the demo and 11 on the tests' board, which few
#: renders there show a knee in (1.4, 1.8 and 7 before; 1 / spp names 1.5, 3.5 and 13).
#: Renders of other seeds (24 a view, the tests' board and a coarse one) named as little
#: as 0.54 times, once in 48 coarse renders at 256 spp: a gain of 0.65, 3 standard errors
#: below the 0.93 that board's strata leave there (1 / spp named 1.24 times); 1 / spp
#: itself named 0.79 at 64 spp, the render's own spread. Other readings tried (the
#: samples' own variance's spread added to the error, 1.5 or 2 standard errors, the knee
#: read 0 to 2 errors up once 2.5 tell one) lowered the mean only where they also named
#: under 0.85 times somewhere.
GAIN_FLOOR = 0.97


def knee_spp(spp: int, variance: float, unstratified: float, error: float = 0.0) -> float | None:
    """The sample count past which a render's noise falls faster than 1 / spp.

    The multi-jitter sampler stratifies each pixel: while its strata are wider than the
    scratches' lobes a pixel's noise falls as unstratified samples' would, as 1 / spp
    (less the little the strata remove at once, :data:`GAIN_FLOOR`); once they resolve
    the lobes it falls faster. The noise's variance at n spp is taken as
    V(n) = G U(n) / (1 + n / knee), U(n) the variance that n unstratified samples leave
    (their own spread over n) and G the floor, so one render, which measures both V and
    U, fixes the knee. Fitted on the demo and a maker's 100 x 80 mm board, 16 to 16560
    spp: the fall steepens from 1 / spp^1.05 to 1 / spp^1.7 near 4096 spp, as this does.

    Args:
        spp: The samples per pixel of the render's two batches.
        variance: The render's noise variance (summed over the pixels).
        unstratified: What ``spp`` unstratified samples would leave (summed alike).
        error: The standard error of the gain ``variance / unstratified``; the knee is
            read from the gain :data:`KNEE_ERRORS` of them above it.

    Returns:
        The knee in samples per pixel; None where the render shows no gain over 1 / spp
        beyond the floor.
    """
    if not (unstratified > 0 and variance > 0):
        return None
    gain = (variance / unstratified + KNEE_ERRORS * error) / GAIN_FLOOR
    return spp * gain / (1 - gain) if gain < 1 else None


@dataclass(frozen=True)
class PartNoise:
    """One part of a render, as its noise tells the knee.

    Attributes:
        batch: Samples per pixel of each batch (of the largest, where a noise target
            added batches of another size).
        batches: How many batches of that size.
        variance: Per pixel, the squared standard error of those batches' mean.
        unstratified: Per pixel, what as many unstratified samples would leave.
        rendered: Per pixel, the squared standard error of the part's image, where it
            also holds earlier rounds (None: ``variance``).
    """

    batch: int
    batches: int
    variance: np.ndarray
    unstratified: np.ndarray
    rendered: np.ndarray | None = None

    @property
    def leaves(self) -> np.ndarray:
        """Per pixel, the squared standard error of the part's image."""
        return self.variance if self.rendered is None else self.rendered


def render_knee(parts: Sequence[PartNoise]) -> tuple[float | None, float]:
    """A render's knee, and the samples per pixel at which two batches leave its noise.

    Both are for two batches, as a render of ``--spp`` takes them. Each batch is
    stratified on its own: k batches of b samples leave 2 / k of the variance two of them
    leave, at the same gain over unstratified samples, so two batches of b fix the knee
    (k b samples overstated it k / 2 times), and k batches leave more noise than two of
    k b / 2 samples: the advice counts from the count of two batches that leave as much,
    by the knee's model; so does a render whose noise target added batches of another
    size (the part describes the largest, and ``rendered`` the image's noise). Each part
    counts as two of its
    batches would; the gain's
    standard error (:data:`KNEE_ERRORS`) is the larger of its spread over the pixels and
    the one the batches' own spread gives it (:func:`gain_error`), and batches of fewer
    than :data:`MIN_KNEE_BATCH` samples fix no knee. The smooth flat part of a spec
    render (:class:`~scratchfab.verify.verify.BoardRenderer`) counts with its own batch
    size: it holds about 0.1 % of the noise, so its gain moves the knee by as little.

    Args:
        parts: The render's parts, the first the one whose batches make its spp.

    Returns:
        The knee (None: the render shows none), and that count (the samples taken where
        every part took two batches).
    """
    spp = 2 * parts[0].batch
    variance = sum(p.batches / 2 * np.asarray(p.variance, np.float64) for p in parts)
    loose = sum(p.batches / 2 * np.asarray(p.unstratified, np.float64) for p in parts)
    sums = [float(np.sum(p.variance, dtype=np.float64)) for p in parts]
    # Summed part by part for both, so that two batches of every part count as the spp exactly.
    total = sum(p.batches / 2 * s for p, s in zip(parts, sums, strict=True))
    measured = sum(
        s if p.rendered is None else float(np.sum(p.rendered, dtype=np.float64))
        for p, s in zip(parts, sums, strict=True)
    )
    free = float(np.sum(loose))
    knee = None
    if parts[0].batch >= MIN_KNEE_BATCH and free > 0:
        knee = knee_spp(spp, total, free, gain_error(variance, loose, parts[0].batches))
    if not measured > 0:
        return knee, float(parts[0].batch * parts[0].batches)
    return knee, spp_for(spp, total / measured, knee)


def gain_error(
    variance: np.ndarray | float, unstratified: np.ndarray | float, batches: int
) -> float:
    """The standard error of a render's gain ``sum(variance) / sum(unstratified)``.

    The larger of two estimates: the pixels' spread about the gain (each pixel's variance
    against its unstratified one times the gain), and the spread that the batches' own
    estimate of a pixel's variance has (k batches: k - 1 degrees of freedom, so a standard
    deviation of sqrt(2 / (k - 1)) times the variance, the gain times the unstratified
    one). A few bright pixels carry much of a small board's noise; where their batches
    happen to agree, the first estimate falls with the gain and the knee came out too low.
    """
    v, u = np.asarray(variance, np.float64), np.asarray(unstratified, np.float64)
    free = float(np.sum(u))
    gain = float(np.sum(v)) / free
    spread = math.sqrt(float(np.sum((v - gain * u) ** 2)))
    own = gain * math.sqrt(2.0 / max(1, batches - 1) * float(np.sum(u**2)))
    return max(spread, own) / free


def variance_ratio(spp: float, more: float, knee: float | None) -> float:
    """How many times less noise variance ``more`` spp leave than ``spp`` (the knee's model)."""
    slope = 0.0 if knee is None else 1.0 / knee
    return more * (1 + more * slope) / (spp * (1 + spp * slope))


def spp_for(spp: float, factor: float, knee: float | None) -> float:
    """The samples per pixel that leave ``1 / factor`` of ``spp``'s noise variance."""
    if factor == 1:
        return float(spp)
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
    return _positive(entry.get("noise_knee_spp"))


def _counted_from(entry: Mapping[str, Any], spp: float) -> float:
    """The count the advice counts from: two batches as noisy as the render (:func:`render_knee`).

    ``noise_equivalent_spp`` where recorded, else the render's ``spp``.
    """
    return _positive(entry.get("noise_equivalent_spp")) or spp


def _positive(value: Any) -> float | None:
    """``value`` as a float where it is a finite number above 0, else None."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return None
    return float(value) if math.isfinite(value) and value > 0 else None


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
    knee, base = _knee(entry), _counted_from(entry, spp)
    if free is None:
        more = more_spp(base * NOISY_SPP_FACTOR)
    else:
        # Where the gate fails for noise alone, half the way from the gate to the
        # noise-free rho is left to the noise, so the named count passes it.
        loss = NOISE_RHO_LOSS
        if min_rho is not None and effect.rho < min_rho < free:
            loss = min(loss, (free - min_rho) / 2)
        factor = effect.variance_factor(loss) or 1.0
        if factor <= 1.0:
            return ""
        more = more_spp(spp_for(base, factor, knee))
    ratio = variance_ratio(base, more, knee)
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
    quiet, base = QUIET_MAP_SHARE, _counted_from(entry, spp)
    if share < 1:
        factor = share * (1 - quiet) / (quiet * (1 - share))
        more = more_spp(spp_for(base, factor, _knee(entry)))
    else:
        more = more_spp(base * NOISY_SPP_FACTOR)
    then = f"brings it under {100 * quiet:.0f} %" if share < 1 else "at least"
    return (
        f"{'mostly ' if share >= 0.5 else ''}sampling noise: about {100 * share:.0f} % of "
        f"these differences is the render's noise, not the board; {spp_setting} {more} {then}"
    )
