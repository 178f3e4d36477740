"""Closed-form footprint NDF of one scratch (SPEC sections 3, 4 and 8; supplement eqs. 1-9).

For a pixel footprint P (a quadrilateral on the board) and a scratch S (the rectangle
|x| <= w, 0 <= y <= L of its own frame: x across, y along from p0), this module computes

    integral over P ∩ S of D(h . n(x)) dA      and      |P ∩ S|

exactly, vectorised over (footprint, scratch) pairs in Dr.Jit and differentiable with
respect to the scratch's endpoints, the half-vector and the footprint's corners.

Method. The integrand depends on x only, so Green's theorem turns the area integral into
-∮_P clamp(y, 0, L) f(x) dx along P's edges (eq. 3), with x clamped to the scratch's
width (eq. 1) and, for the NDF, further to the part of the profile where h . n > 0
(D = 0 elsewhere, SPEC section 4; that part is one interval because the other root of
h . n = 0 lies at |t| >= 1). Writing clamp(y, 0, L) = y+ - (y - L)+ splits every edge,
branch-free, into two pieces on which the weight S(x) is linear (eq. 4). In t = 2x/wbar,

    D = alpha^2/pi * R(t),   R = (1 + t^2)^4 / (Q1(t)^2 Q2(t)^2)        (eq. 7)

and R = c0 + sum over the four complex roots z of Q1, Q2 (eq. 8) of
A/(t - z) + B/(t - z)^2 (partial fractions; the roots come in conjugate pairs, so the sum
is twice the real part over z1 = root of Q1 and z2 = -1/z1 = root of Q2). Our closed forms
for the coefficients (eq. 9's v; double-pole residues, using Q2(z1) = 2 (1 + z1^2)):

    q1 = 1 + r h_z,  q2 = 1 - r h_z,  beta = sqrt(1 - r^2 (h_x^2 + h_z^2)),  r^2 = 1 - alpha^2
    z1 = (-r h_x + i beta) / q1,   c0 = 1 / (q1 q2)^2
    B1 = -(1 + z1^2)^2 / (16 beta^2),   A1 = B1 (6 z1/(1 + z1^2) - q1 conj(z1) + i q1/beta)
    B2 = B1 / z1^4,   A2 = A1 / z1^2 - 2 B1 / z1^3.

Rather than differencing an antiderivative at the two ends of a piece [t_a, t_a + delta]
(which cancels badly for short pieces, near-real roots and far roots), each piece is
evaluated in relative form: with c = t_a - z and eps = delta / c,

    integral of R            = delta   (c0   + 2 Re sum A/c l(eps)  + B/c^2 / (1 + eps))
    integral of (t - t_a) R  = delta^2 (c0/2 + 2 Re sum A/c n1(eps) + B/c^2 n2(eps))

where l = log(1 + eps)/eps, n1 = (1 - l)/eps, n2 = (l - 1/(1 + eps))/eps are the moments
of 1/(1 + eps s) and 1/(1 + eps s)^2 over s in [0, 1]: a power series (of atanh) for |eps| < 1/4,
the complex logarithm otherwise. arg(1 + eps) = arg(t_b - z) - arg(t_a - z) is continuous
because Im z != 0.

Precision: float64. The coefficients are as large as c0 ~ 1/alpha^4 while R >= 1, so
float64 loses up to log10(1/alpha^4) digits where a footprint sees only the far tail of a
sharp lobe with h at the normal: measured worst error 6.1e-7 of the integral of |S| D over
10,000 random cases with alpha >= 0.005 (tests/test_ndf.py, SCRATCHFAB_FULL=1), typically
1e-12. In float32 the same cancellation leaves no correct digit (benchmarks/bench_ndf.py
measures it), so pass Float64 arrays. Below alpha = 0.005 the worst error grows as 1/alpha^4.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import drjit as dr
import numpy as np

_SERIES_RADIUS = 0.25
_SERIES_TERMS = 10  # |Y| <= (0.25/1.75)^2: 0.0204^10 < 1e-16

Complex = tuple[Any, Any]


def _cmul(a: Complex, b: Complex) -> Complex:
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _cdiv(a: Complex, b: Complex) -> Complex:
    inv = dr.rcp(b[0] * b[0] + b[1] * b[1])
    return (a[0] * b[0] + a[1] * b[1]) * inv, (a[1] * b[0] - a[0] * b[1]) * inv


def _cadd(a: Complex, b: Complex) -> Complex:
    return a[0] + b[0], a[1] + b[1]


def _cselect(mask: Any, a: Complex, b: Complex) -> Complex:
    return dr.select(mask, a[0], b[0]), dr.select(mask, a[1], b[1])


def _moments(eps: Complex) -> tuple[Complex, Complex, Complex, Complex]:
    """l, 1/(1 + eps), n1, n2 of the module docstring, accurate for every eps off [-inf, -1]."""
    small = eps[0] * eps[0] + eps[1] * eps[1] < _SERIES_RADIUS**2
    one_eps = (1.0 + eps[0], eps[1])
    inv1 = _cdiv((1.0, 0.0), one_eps)
    # series: log(1 + eps) = 2 atanh(y), y = eps/(2 + eps), so with Y = y^2
    # n1 = 1/(2 + eps) - 2 eps/(2 + eps)^3 sum_j Y^j/(2j + 3)   (eps kept small elsewhere)
    es = (dr.select(small, eps[0], 0.0), dr.select(small, eps[1], 0.0))
    inv2 = _cdiv((1.0, 0.0), (2.0 + es[0], es[1]))
    y = _cmul(es, inv2)
    yy = _cmul(y, y)
    acc: Complex = (1.0 / (2 * _SERIES_TERMS + 1), 0.0)
    for j in range(_SERIES_TERMS - 2, -1, -1):
        acc = _cmul(acc, yy)
        acc = (acc[0] + 1.0 / (2 * j + 3), acc[1])
    tail = _cmul(_cmul(_cmul(es, inv2), _cmul(inv2, inv2)), acc)
    n1_s = (inv2[0] - 2.0 * tail[0], inv2[1] - 2.0 * tail[1])
    ell_s = (1.0 - (es[0] * n1_s[0] - es[1] * n1_s[1]), -(es[0] * n1_s[1] + es[1] * n1_s[0]))
    n2_s = (inv1[0] - n1_s[0], inv1[1] - n1_s[1])
    # logarithm (eps kept away from 0 elsewhere; where it is not, inv1 is not 1/(1 + ed),
    # but those lanes take the series)
    ed = (dr.select(small, _SERIES_RADIUS, eps[0]), dr.select(small, 0.0, eps[1]))
    od = (1.0 + ed[0], ed[1])
    inv_ed = _cdiv((1.0, 0.0), ed)
    log1p = (0.5 * dr.log(od[0] * od[0] + od[1] * od[1]), dr.atan2(od[1], od[0]))
    ell_d = _cmul(log1p, inv_ed)
    n1_d = _cmul((1.0 - ell_d[0], -ell_d[1]), inv_ed)
    n2_d = _cmul((ell_d[0] - inv1[0], ell_d[1] - inv1[1]), inv_ed)
    return (
        _cselect(small, ell_s, ell_d),
        inv1,
        _cselect(small, n1_s, n1_d),
        _cselect(small, n2_s, n2_d),
    )


def _lobe_root(hx: Any, hz: Any, alpha: Any) -> tuple[Any, Any, Any, Complex]:
    """(q1, q2, beta, z1): Q1's leading coefficient, Q2's, and Q1's root z1 (eq. 8).

    Re z1 is the t where h . n(t) peaks (the lobe's centre) and Im z1 = beta / q1 its width.
    """
    a2 = alpha * alpha
    r = dr.sqrt(1.0 - a2)
    q1 = 1.0 + r * hz
    # 1 - r^2 h_z^2 and beta^2 = 1 - r^2 (h_x^2 + h_z^2) without cancellation: c0 and the
    # far root's terms cancel to ~alpha^4 relative when h is near the normal, so these
    # must be accurate to a few ulps of themselves
    one_hz2 = (1.0 - hz) * (1.0 + hz)
    q2 = (one_hz2 + a2 * hz * hz) / q1
    beta2 = one_hz2 - hx * hx + a2 * (hx * hx + hz * hz)
    beta = dr.sqrt(dr.maximum(beta2, a2 * 1e-3))
    return q1, q2, beta, (-r * hx / q1, beta / q1)


class _Poles:
    """Partial-fraction data of R(t) (eqs. 7-9) for one half-vector per lane."""

    def __init__(self, hx: Any, hz: Any, alpha: Any) -> None:
        q1, q2, beta, z1 = _lobe_root(hx, hz, alpha)
        w1 = (1.0 + z1[0] * z1[0] - z1[1] * z1[1], 2.0 * z1[0] * z1[1])  # 1 + z1^2
        k = 1.0 / (16.0 * beta * beta)
        mw1 = (-k * w1[0], -k * w1[1])  # B1 / (1 + z1^2)
        b1 = _cmul(mw1, w1)
        # A1 = B1/(1 + z1^2) (6 z1 + (1 + z1^2) f), f = -q1 conj(z1) + i q1/beta: no division
        # by 1 + z1^2, which is 0 at alpha = 1 (r = 0, z1 = i), where A1 = B1 = 0 (R = 1)
        f = (-q1 * z1[0], q1 * z1[1] + q1 / beta)
        g = _cadd((6.0 * z1[0], 6.0 * z1[1]), _cmul(w1, f))
        a1 = _cmul(mw1, g)
        inv_z = _cdiv((1.0, 0.0), z1)
        inv_z2 = _cmul(inv_z, inv_z)
        inv_z3 = _cmul(inv_z2, inv_z)
        a2c = _cmul(a1, inv_z2)
        b1z3 = _cmul(b1, inv_z3)
        self.c0 = 1.0 / (q1 * q1 * q2 * q2)
        self._parts = (q1, beta, z1, w1, k, mw1, f, g, b1, a1, inv_z, inv_z2, b1z3, a2c)
        a2 = alpha * alpha
        beta2 = (1.0 - hz) * (1.0 + hz) - hx * hx + a2 * (hx * hx + hz * hz)
        self._beta_on = beta2 > a2 * 1e-3  # as in _lobe_root
        self._r = dr.sqrt(1.0 - alpha * alpha)
        self._hx = hx
        self.roots = [
            (z1, a1, b1),
            (
                (-inv_z[0], -inv_z[1]),
                (a2c[0] - 2.0 * b1z3[0], a2c[1] - 2.0 * b1z3[1]),
                _cmul(b1z3, inv_z),
            ),
        ]

    def d_hx(self) -> list[tuple[Complex, Complex, Complex]]:
        """Per root (dz/dh_x, dA/dh_x, dB/dh_x): the derivatives of :attr:`roots` (c0 has none).

        Forward-mode differentiation of the construction above, written out; where beta is
        clamped at its floor, dbeta = 0 (as dr.maximum's derivative).
        """
        q1, beta, z1, w1, k, mw1, f, g, b1, a1, inv_z, inv_z2, b1z3, a2c = self._parts
        a2 = 1.0 - self._r * self._r
        dbeta = dr.select(self._beta_on, -self._hx * (1.0 - a2) / beta, 0.0)
        dz1 = (-self._r / q1, dbeta / q1)
        dw1 = _cmul((2.0 * z1[0], 2.0 * z1[1]), dz1)
        dk = -2.0 * k * dbeta / beta
        dmw1 = (-(dk * w1[0] + k * dw1[0]), -(dk * w1[1] + k * dw1[1]))
        db1 = _cadd(_cmul(dmw1, w1), _cmul(mw1, dw1))
        df = (-q1 * dz1[0], q1 * dz1[1] - q1 * dbeta / (beta * beta))
        dg = _cadd((6.0 * dz1[0], 6.0 * dz1[1]), _cadd(_cmul(dw1, f), _cmul(w1, df)))
        da1 = _cadd(_cmul(dmw1, g), _cmul(mw1, dg))
        dinv_z = _cmul(inv_z2, dz1)
        dinv_z = (-dinv_z[0], -dinv_z[1])
        dinv_z2 = _cmul((2.0 * inv_z[0], 2.0 * inv_z[1]), dinv_z)
        dinv_z3 = _cmul((3.0 * inv_z2[0], 3.0 * inv_z2[1]), dinv_z)
        inv_z3 = _cmul(inv_z2, inv_z)
        da2c = _cadd(_cmul(da1, inv_z2), _cmul(a1, dinv_z2))
        db1z3 = _cadd(_cmul(db1, inv_z3), _cmul(b1, dinv_z3))
        return [
            (dz1, da1, db1),
            (
                (-dinv_z[0], -dinv_z[1]),
                (da2c[0] - 2.0 * db1z3[0], da2c[1] - 2.0 * db1z3[1]),
                _cadd(_cmul(db1z3, inv_z), _cmul(b1z3, dinv_z)),
            ),
        ]

    def piece(self, ta: Any, delta: Any) -> tuple[Any, Any]:
        """(E0, E1): integrals of R and (t - t_a) R over [t_a, t_a + delta], over delta^(1, 2)."""
        e0, e1, _ = self.piece_parts(ta, delta)
        return e0, e1

    def piece_parts(self, ta: Any, delta: Any) -> tuple[Any, Any, list[Any]]:
        """:meth:`piece` and, per root, (1/c, eps, l, 1/(1 + eps), n1, n2) of the docstring."""
        e0 = self.c0
        e1 = 0.5 * self.c0
        parts = []
        for z, a, b in self.roots:
            c = (ta - z[0], -z[1])
            inv_c = _cdiv((1.0, 0.0), c)
            eps = (delta * inv_c[0], delta * inv_c[1])
            pa = _cmul(a, inv_c)
            pb = _cmul(_cmul(b, inv_c), inv_c)
            ell, inv1, n1, n2 = _moments(eps)
            e0 = e0 + 2.0 * (_cmul(pa, ell)[0] + _cmul(pb, inv1)[0])
            e1 = e1 + 2.0 * (_cmul(pa, n1)[0] + _cmul(pb, n2)[0])
            parts.append((inv_c, eps, ell, inv1, n1, n2))
        return e0, e1, parts


def _r_direct(t: Any, hx: Any, hz: Any, alpha: Any) -> Any:
    """R(t) of eq. 7 from its rational form (SPEC section 8), for the derivative's ends."""
    p = 1.0 + t * t
    c = hz * (1.0 - t * t) - 2.0 * hx * t
    den = p * p - (1.0 - alpha * alpha) * c * c
    return dr.square(p * p / den)


class _PieceSums(dr.CustomOp):
    """The pieces of :func:`_closed_form_pieces` for several edges of one footprint.

    The same values; the derivative is written out instead of traced. With
    g = scale * integral over [x0, x1] of v(x) R(2 x / wbar) dx and v linear from v0 to
    v1 (dv = v1 - v0, dx = x1 - x0; E0, E1 of :meth:`_Poles.piece`):

        dg/dv0 = scale dx (E0 - E1),   dg/dv1 = scale dx E1,
        dg/dx0 = -scale (v0 R(t0) + dv (E0 - E1)),   dg/dx1 = scale (v1 R(t1) - dv E1),

    and dg/dh_x from each pole's dz, dA, dB (:meth:`_Poles.d_hx`): the moments of
    1/(c + delta s)^2 and ^3 that it needs are 1/(1 + eps)^2 (1 + eps/2) and
    1/(2 (1 + eps)^2) (with weight s), free of cancellation. Derivatives with respect to
    h_z, wbar and alpha are not provided: use it only where those carry none.
    """

    def eval(self, x0: Any, x1: Any, v0: Any, v1: Any, hxl: Any, hz: Any, wbar: Any, alpha: Any):  # type: ignore[no-untyped-def]  # noqa: D102
        self.args = (x0, x1, v0, v1, hxl, hz, wbar, alpha)
        self.poles = _Poles(hxl, hz, alpha)
        self.scale = alpha * alpha / math.pi
        self.parts = []
        out = []
        for a, b, va, vb in zip(x0, x1, v0, v1, strict=True):
            ta, delta = 2.0 * a / wbar, 2.0 * (b - a) / wbar
            e0, e1, roots = self.poles.piece_parts(ta, delta)
            self.parts.append((e0, e1, roots))
            out.append(self.scale * (b - a) * (va * e0 + (vb - va) * e1))
        return out

    def _partials(self) -> list[tuple[Any, Any, Any, Any, Any]]:
        """Per piece (dg/dx0, dg/dx1, dg/dv0, dg/dv1, dg/dh_x)."""
        x0, x1, v0, v1, hxl, hz, wbar, alpha = self.args
        d_roots = self.poles.d_hx()
        out = []
        for a, b, va, vb, (e0, e1, roots) in zip(x0, x1, v0, v1, self.parts, strict=True):
            s, dv, dx = self.scale, vb - va, b - a
            r0 = _r_direct(2.0 * a / wbar, hxl, hz, alpha)
            r1 = _r_direct(2.0 * b / wbar, hxl, hz, alpha)
            de0 = 0.0
            de1 = 0.0
            for (_z, big_a, big_b), (dz, da, db), (inv_c, eps, ell, inv1, n1, n2) in zip(
                self.poles.roots, d_roots, roots, strict=True
            ):
                inv_c2 = _cmul(inv_c, inv_c)
                inv_c3 = _cmul(inv_c2, inv_c)
                inv1sq = _cmul(inv1, inv1)
                m3 = _cmul(inv1sq, (1.0 + 0.5 * eps[0], 0.5 * eps[1]))
                n3 = (0.5 * inv1sq[0], 0.5 * inv1sq[1])
                a_c2 = _cmul(big_a, inv_c2)
                b_c3 = _cmul(big_b, inv_c3)
                t0 = _cadd(
                    _cadd(_cmul(_cmul(da, inv_c), ell), _cmul(_cmul(db, inv_c2), inv1)),
                    _cmul(dz, _cadd(_cmul(a_c2, inv1), _cmul((2.0 * b_c3[0], 2.0 * b_c3[1]), m3))),
                )
                t1 = _cadd(
                    _cadd(_cmul(_cmul(da, inv_c), n1), _cmul(_cmul(db, inv_c2), n2)),
                    _cmul(dz, _cadd(_cmul(a_c2, n2), _cmul((2.0 * b_c3[0], 2.0 * b_c3[1]), n3))),
                )
                de0 = de0 + 2.0 * t0[0]
                de1 = de1 + 2.0 * t1[0]
            out.append(
                (
                    -s * (va * r0 + dv * (e0 - e1)),
                    s * (vb * r1 - dv * e1),
                    s * dx * (e0 - e1),
                    s * dx * e1,
                    s * dx * (va * de0 + dv * de1),
                )
            )
        return out

    def forward(self) -> None:  # noqa: D102
        g: list[Any] = [self.grad_in(k) for k in ("x0", "x1", "v0", "v1")]
        gh = self.grad_in("hxl")
        out = []
        for n, (p0, p1, q0, q1, ph) in enumerate(self._partials()):
            out.append(p0 * g[0][n] + p1 * g[1][n] + q0 * g[2][n] + q1 * g[3][n] + ph * gh)
        self.set_grad_out(out)

    def backward(self) -> None:  # noqa: D102
        go: Any = self.grad_out()
        partials = self._partials()
        for k, name in enumerate(("x0", "x1", "v0", "v1")):
            self.set_grad_in(name, [p[k] * g for p, g in zip(partials, go, strict=True)])
        gh = 0.0
        for p, g in zip(partials, go, strict=True):
            gh = gh + p[4] * g
        self.set_grad_in("hxl", gh)

    def name(self) -> str:  # noqa: D102
        return "footprint pieces"


def _ndf_cutoff(hx: Any, hz: Any, half_width: Any, wbar: Any) -> tuple[Any, Any]:
    """[x_lo, x_hi]: the part of |x| <= w where h . n(x) > 0 (D = 0 outside, SPEC section 4).

    h . n = 0 at the roots of h_z t^2 + 2 h_x t - h_z (product -1); the one with |t| <= 1 is
    t_s = h_z / (h_x + sign(h_x) |h|), and h . n > 0 on the side of t_s toward -sign(h_x).
    """
    rho = dr.sqrt(hx * hx + hz * hz)
    den = hx + dr.select(hx >= 0, rho, -rho)
    ts = hz / dr.select(den == 0, 1.0, den)
    xcut = 0.5 * wbar * ts
    x_lo = dr.select(hx < 0, dr.maximum(-half_width, xcut), -half_width)
    x_hi = dr.select(hx >= 0, dr.minimum(half_width, xcut), half_width)
    return x_lo, dr.maximum(x_hi, x_lo)


def _edge_piece(
    xa: Any, ya: Any, dx: Any, dy: Any, x_lo: Any, x_hi: Any, k: Any
) -> tuple[Any, Any, Any, Any]:
    """The part of edge (xa, ya) + lam (dx, dy) with x in [x_lo, x_hi] and y > k.

    Returns (x0, x1, v0, v1): its ends in edge order and y - k there (>= 0); x0 == x1 when
    the part is empty.
    """
    dxs = dr.select(dx == 0, 1.0, dx)
    lam1 = dr.clip((dr.clip(xa, x_lo, x_hi) - xa) / dxs, 0.0, 1.0)
    lam2 = dr.clip((dr.clip(xa + dx, x_lo, x_hi) - xa) / dxs, 0.0, 1.0)
    lam2 = dr.maximum(lam1, lam2)
    lam_k = (k - ya) / dr.select(dy == 0, 1.0, dy)
    lo = dr.clip(dr.select(dy > 0, dr.maximum(lam1, lam_k), lam1), lam1, lam2)
    hi = dr.select(dy < 0, dr.minimum(lam2, lam_k), lam2)
    hi = dr.select((dy == 0) & (ya <= k), lo, dr.maximum(hi, lo))
    return (
        xa + lo * dx,
        xa + hi * dx,
        dr.maximum(ya + lo * dy - k, 0.0),
        dr.maximum(ya + hi * dy - k, 0.0),
    )


PieceFn = Callable[[Any, Any, Any, Any], Any]


def _frame(p0x: Any, p0y: Any, p1x: Any, p1y: Any) -> tuple[Any, Any, Any]:
    """(ux, uy, L): the scratch's unit direction and length (direction (0, 1) when L = 0)."""
    ex, ey = p1x - p0x, p1y - p0y
    length = dr.sqrt(dr.maximum(ex * ex + ey * ey, 1e-300))
    inv_len = dr.rcp(dr.select(length > 0, length, 1.0))
    ux = dr.select(length > 0, ex * inv_len, 0.0)
    uy = dr.select(length > 0, ey * inv_len, 1.0)
    return ux, uy, length


def _local(qx: Any, qy: Any, p0x: Any, p0y: Any, ux: Any, uy: Any) -> tuple[Any, Any]:
    """A board point in the right-handed scratch frame: x across (uy, -ux), y along (ux, uy)."""
    rx, ry = qx - p0x, qy - p0y
    return rx * uy - ry * ux, rx * ux + ry * uy


def _local_quad(
    quad_x: Sequence[Any], quad_y: Sequence[Any], p0x: Any, p0y: Any, ux: Any, uy: Any
) -> tuple[list[Any], list[Any]]:
    """A footprint's corners in the scratch frame of :func:`_local`: (x list, y list)."""
    lx, ly = [], []
    for qx, qy in zip(quad_x, quad_y, strict=True):
        x, y = _local(qx, qy, p0x, p0y, ux, uy)
        lx.append(x)
        ly.append(y)
    return lx, ly


def quad_orientation(quad_x: Sequence[Any], quad_y: Sequence[Any]) -> Any:
    """+1 for a counter-clockwise quadrilateral, -1 for a clockwise one (shoelace sign)."""
    n = len(quad_x)
    signed = type(quad_x[0])(0.0)
    for i in range(n):
        j = (i + 1) % n
        signed = signed + (quad_x[i] * quad_y[j] - quad_x[j] * quad_y[i])
    return dr.select(signed < 0, -1.0, 1.0)


def _edge(
    xa: Any,
    ya: Any,
    xb: Any,
    yb: Any,
    k: Any,
    half_width: Any,
    x_lo: Any,
    x_hi: Any,
    piece: PieceFn,
) -> tuple[Any, Any]:
    """(line integral of S D, twice the area term) of edge a -> b's part with y > k (eq. 4)."""
    dx, dy = xb - xa, yb - ya
    a0, a1, av0, av1 = _edge_piece(xa, ya, dx, dy, -half_width, half_width, k)
    x0, x1, v0, v1 = _edge_piece(xa, ya, dx, dy, x_lo, x_hi, k)
    return piece(x0, x1, v0, v1), (a1 - a0) * (av0 + av1)


def _footprint(
    quad_x: Sequence[Any],
    quad_y: Sequence[Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    hx: Any,
    hy: Any,
    hz: Any,
    make_piece: Callable[[Any], PieceFn],
    with_magnitude: bool = False,
) -> tuple[Any, Any, Any]:
    """(NDF integral, covered area, sum over P's edges of |integral of S(x) D dx|).

    The magnitude is traced only when ``with_magnitude`` (else 0): the render path does not
    need it.
    """
    float_t = type(p0x)
    ux, uy, length = _frame(p0x, p0y, p1x, p1y)
    lx, ly = _local_quad(quad_x, quad_y, p0x, p0y, ux, uy)
    n = len(lx)
    orient = quad_orientation(quad_x, quad_y)
    hxl = hx * uy - hy * ux
    x_lo, x_hi = _ndf_cutoff(hxl, hz, half_width, wbar)
    piece = make_piece(hxl)
    ndf = float_t(0.0)
    area = float_t(0.0)
    magnitude = float_t(0.0)
    for i in range(n):
        j = (i + 1) % n
        edge = float_t(0.0)
        for k, sign in ((0.0, 1.0), (length, -1.0)):
            value, twice_area = _edge(lx[i], ly[i], lx[j], ly[j], k, half_width, x_lo, x_hi, piece)
            area = area + sign * twice_area
            edge = edge + sign * value
        ndf = ndf + edge
        if with_magnitude:
            magnitude = magnitude + dr.abs(edge)
    # Green: integral over the region = -(closed line integral), counter-clockwise
    return -orient * ndf, -0.5 * orient * area, magnitude


def _closed_form_pieces(hz: Any, wbar: Any, alpha: Any) -> Callable[[Any], PieceFn]:
    def make_piece(hxl: Any) -> PieceFn:
        poles = _Poles(hxl, hz, alpha)
        scale = alpha * alpha / math.pi

        def piece(x0: Any, x1: Any, v0: Any, v1: Any) -> Any:
            e0, e1 = poles.piece(2.0 * x0 / wbar, 2.0 * (x1 - x0) / wbar)
            return scale * (x1 - x0) * (v0 * e0 + (v1 - v0) * e1)

        return piece

    return make_piece


def _unit_rule(nodes: int) -> tuple[list[float], list[float]]:
    """Gauss-Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    return [float(v) for v in 0.5 * (x + 1.0)], [float(v) for v in 0.5 * w]


def _weighted_r(hx: Any, hz: Any, r2: Any, t0: Any, dt: Any, v0: Any, dv: Any, s: Any) -> Any:
    """(v0 + s dv) R(t0 + s dt): the piece's integrand, R = (1 + t^2)^4 / (Q1 Q2)^2 (eq. 7)."""
    t = t0 + s * dt
    p = 1.0 + t * t
    c = hz * (1.0 - t * t) - 2.0 * hx * t  # (1 + t^2) h . n (SPEC section 8)
    den = p * p - r2 * c * c  # = Q1 Q2
    return (v0 + s * dv) * dr.square(p * p / den)


def scratch_footprint_ndf(
    quad_x: Sequence[Any],
    quad_y: Sequence[Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    hx: Any,
    hy: Any,
    hz: Any,
    alpha: Any,
) -> tuple[Any, Any]:
    """Exact integral of the GGX NDF over footprint ∩ scratch, and the covered area.

    Args:
        quad_x: the footprint's 4 corners' x (world board coordinates, mm), either orientation.
        quad_y: their y.
        p0x: scratch start x (mm); p0y, p1x, p1y likewise for start y and end point.
        p0y: see p0x.
        p1x: see p0x.
        p1y: see p0x.
        half_width: w (mm), half the tool width.
        wbar: the profile's shape parameter (``profile.solve_wbar``), mm.
        hx: unit half-vector in the world frame, x component.
        hy: its y component.
        hz: its z component (> 0 for any light and camera above the board).
        alpha: GGX roughness (>= 0.005 for the documented accuracy).

    Returns:
        (ndf_integral, covered_area): the integral over P ∩ S of D(h . n(x)) dA in mm^2, and
        |P ∩ S| in mm^2. All arguments are Dr.Jit arrays of one float type (Float64
        recommended, see the module docstring) or broadcastable Python floats.
    """
    make_piece = _closed_form_pieces(hz, wbar, alpha)
    ndf, area, _ = _footprint(
        quad_x, quad_y, p0x, p0y, p1x, p1y, half_width, wbar, hx, hy, hz, make_piece
    )
    return ndf, area


def scratch_footprint_ndf_gl(
    quad_x: Sequence[Any],
    quad_y: Sequence[Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    hx: Any,
    hy: Any,
    hz: Any,
    alpha: Any,
    nodes: int,
) -> tuple[Any, Any]:
    """The same pair of integrals by ``nodes``-point Gauss-Legendre quadrature on every piece.

    A slower, approximate twin of :func:`scratch_footprint_ndf` (same edge decomposition) for
    benchmarks and cross-checks; ``nodes`` must grow as alpha shrinks.
    """
    s_nodes, s_weights = _unit_rule(nodes)

    r2 = 1.0 - alpha * alpha
    scale = alpha * alpha / math.pi

    def make_piece(hxl: Any) -> PieceFn:
        def piece(x0: Any, x1: Any, v0: Any, v1: Any) -> Any:
            total = 0.0
            t0, dt, dv = 2.0 * x0 / wbar, 2.0 * (x1 - x0) / wbar, v1 - v0
            for s, weight in zip(s_nodes, s_weights, strict=True):
                total = total + weight * _weighted_r(hxl, hz, r2, t0, dt, v0, dv, s)
            return scale * (x1 - x0) * total

        return piece

    ndf, area, _ = _footprint(
        quad_x, quad_y, p0x, p0y, p1x, p1y, half_width, wbar, hx, hy, hz, make_piece
    )
    return ndf, area


def scratch_footprint_ndf_graded(
    quad_x: Sequence[Any],
    quad_y: Sequence[Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    hx: Any,
    hy: Any,
    hz: Any,
    alpha: Any,
    panels: int,
    nodes: int,
) -> tuple[Any, Any]:
    """The same pair of integrals by Gauss-Legendre on panels graded around the lobe.

    Every piece (same edge decomposition as :func:`scratch_footprint_ndf`) is split at the
    lobe centre Re z1 (clamped into the piece; z1 the root of Q1, eq. 8) and each side gets
    ``panels`` panels whose lengths grow geometrically with their distance from z1, the first
    as long as that distance (>= the lobe half-width Im z1 ~ alpha), so every panel sees the
    pole at a fixed relative distance; ``nodes`` Gauss-Legendre nodes per panel:
    2 * panels * nodes evaluations of D per piece. Branch-free and differentiable; the
    quadrature that a lobe-aware renderer would use, for benchmarks and cross-checks.
    """
    s_nodes, s_weights = _unit_rule(nodes)
    r2 = 1.0 - alpha * alpha
    scale = alpha * alpha / math.pi

    def make_piece(hxl: Any) -> PieceFn:
        _, _, _, z1 = _lobe_root(hxl, hz, alpha)

        def piece(x0: Any, x1: Any, v0: Any, v1: Any) -> Any:
            t0, dt, dv = 2.0 * x0 / wbar, 2.0 * (x1 - x0) / wbar, v1 - v0
            inv = dr.rcp(dr.select(dt == 0, 1.0, dt))
            # the pole in the piece's parameter s in [0, 1], and its distance from the split
            centre = (z1[0] - t0) * inv
            split = dr.clip(centre, 0.0, 1.0)
            dist = dr.sqrt(dr.square(split - centre) + dr.square(z1[1] * inv))
            total = 0.0
            for side, length in ((-1.0, split), (1.0, 1.0 - split)):
                # breakpoints dist (q^k - 1), k = 0..panels, with q^panels = 1 + length / dist
                step = dr.log(1.0 + length / dist) / panels
                lo = 0.0
                for k in range(1, panels + 1):
                    hi = (
                        length
                        if k == panels
                        else dr.minimum(dist * (dr.exp(k * step) - 1.0), length)
                    )
                    width = hi - lo
                    for s, weight in zip(s_nodes, s_weights, strict=True):
                        u = split + side * (lo + s * width)
                        total = total + (weight * width) * _weighted_r(
                            hxl, hz, r2, t0, dt, v0, dv, u
                        )
                    lo = hi
            return scale * (x1 - x0) * total

        return piece

    ndf, area, _ = _footprint(
        quad_x, quad_y, p0x, p0y, p1x, p1y, half_width, wbar, hx, hy, hz, make_piece
    )
    return ndf, area


def scratch_footprint_ndf_magnitude(
    quad_x: Sequence[Any],
    quad_y: Sequence[Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    hx: Any,
    hy: Any,
    hz: Any,
    alpha: Any,
) -> Any:
    """Sum over P's edges of |integral of S(x) D dx| (closed form), arguments as above.

    The integral of |S| D along the footprint's edges: the scale the accuracy of
    :func:`scratch_footprint_ndf` is stated against (module docstring, issue acceptance).
    """
    make_piece = _closed_form_pieces(hz, wbar, alpha)
    return _footprint(
        quad_x, quad_y, p0x, p0y, p1x, p1y, half_width, wbar, hx, hy, hz, make_piece, True
    )[2]


#: Number of terms of a footprint in :func:`scratch_edges_ndf`; slot 2 i + far is edge i
#: (corner i to corner i + 1) with far 0 (the kink y = 0) or 1 (y = L).
EDGE_SLOTS = 8


def scratch_edges_ndf(
    edges: Sequence[tuple[Any, Any, Any, Any, Any]],
    orient: Any,
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    wbar: Any,
    hx: Any,
    hy: Any,
    hz: Any,
    alpha: Any,
    custom_derivative: bool = False,
) -> tuple[Any, Any]:
    """The sum of some of the eight terms whose sum is :func:`scratch_footprint_ndf`.

    Green's line integral (eq. 3) with clamp(y, 0, L) = y+ - (y - L)+ is a sum over the
    footprint's 4 edges and the two kinks k = 0, L of eq. 4's pieces. Most of the eight
    terms of a (pixel, scratch) pair are exactly 0 (:func:`edge_piece_masks`); passing
    only the others gives the same integrals for a fraction of the work (the scratch's
    frame and poles are shared by the terms, as in :func:`scratch_footprint_ndf`).

    Args:
        edges: per term (ax, ay, bx, by, far): the edge from corner a to the next corner
            b of the footprint (mm), and far (Dr.Jit Bool): the term of the kink k = L
            (True) or k = 0 (False).
        orient: :func:`quad_orientation` of the whole footprint.
        p0x: scratch start x (mm), and the other arguments as :func:`scratch_footprint_ndf`.
        p0y: see p0x.
        p1x: see p0x.
        p1y: see p0x.
        half_width: see p0x.
        wbar: see p0x.
        hx: see p0x.
        hy: see p0x.
        hz: see p0x.
        alpha: see p0x.
        custom_derivative: differentiate the closed form by its written-out derivative
            (:class:`_PieceSums`, about half the work of tracing it) where h_z, wbar and
            alpha carry no derivative; the values are the same.

    Returns:
        (ndf_integral, covered_area) of the terms passed, in mm^2.
    """
    float_t = type(p0x)
    ux, uy, length = _frame(p0x, p0y, p1x, p1y)
    hxl = hx * uy - hy * ux
    x_lo, x_hi = _ndf_cutoff(hxl, hz, half_width, wbar)
    area = float_t(0.0)
    ends: list[list[Any]] = [[], [], [], []]
    for ax, ay, bx, by, far in edges:
        xa, ya = _local(ax, ay, p0x, p0y, ux, uy)
        xb, yb = _local(bx, by, p0x, p0y, ux, uy)
        k = dr.select(far, length, 0.0)
        dx, dy = xb - xa, yb - ya
        a0, a1, av0, av1 = _edge_piece(xa, ya, dx, dy, -half_width, half_width, k)
        twice_area = (a1 - a0) * (av0 + av1)
        area = area + dr.select(far, -twice_area, twice_area)
        for out, value in zip(ends, _edge_piece(xa, ya, dx, dy, x_lo, x_hi, k), strict=True):
            out.append(value)
    if custom_derivative and not any(dr.grad_enabled(v) for v in (hz, wbar, alpha)):
        values = dr.custom(_PieceSums, *ends, hxl, hz, wbar, alpha)  # type: ignore[call-arg]
    else:
        piece = _closed_form_pieces(hz, wbar, alpha)(hxl)
        values = [piece(*term) for term in zip(*ends, strict=True)]
    ndf = float_t(0.0)
    for (*_corners, far), value in zip(edges, values, strict=True):
        ndf = ndf + dr.select(far, -value, value)
    # Green: integral over the region = -(closed line integral), counter-clockwise
    return -orient * ndf, -0.5 * orient * area


def edge_piece_masks(
    quad_x: Sequence[Any],
    quad_y: Sequence[Any],
    p0x: Any,
    p0y: Any,
    p1x: Any,
    p1y: Any,
    half_width: Any,
    slack: float,
) -> list[Any]:
    """Per slot (:data:`EDGE_SLOTS`), False where that term of the footprint is exactly 0.

    A term is dropped only when its edge, in the scratch's frame, lies more than ``slack``
    (mm) beyond one side of the band |x| <= w, or more than ``slack`` below its kink
    y = k. Its piece (:func:`_edge_piece`) then has equal ends, so the term is exactly 0
    with exactly zero derivatives; ``slack`` covers the rounding of the frame between
    this kernel and the one that evaluates the terms. Arguments as
    :func:`scratch_footprint_ndf`.
    """
    ux, uy, length = _frame(p0x, p0y, p1x, p1y)
    lx, ly = _local_quad(quad_x, quad_y, p0x, p0y, ux, uy)
    w = half_width + slack
    masks = []
    n = len(lx)
    for i in range(n):
        j = (i + 1) % n
        across = (dr.minimum(lx[i], lx[j]) <= w) & (dr.maximum(lx[i], lx[j]) >= -w)
        top = dr.maximum(ly[i], ly[j]) + slack
        masks.append(across & (top >= 0.0))
        masks.append(across & (top >= length))
    return masks
