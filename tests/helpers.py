"""Closed-form references and balance checks shared by the tests (no finray_jax internals)."""

import numpy as np
from scipy import optimize, special


def bisshopp_drucker(alpha):
    """Large-deflection elastica of a cantilever under a dead tip force perpendicular to its
    undeformed axis (Bisshopp and Drucker 1945), for alpha = P L^2 / EI.

    The rod starts along +z, the force is +x. With theta(s) the tangent angle from +z
    toward +x, EI theta' = P (z(L) - z(s)), so EI theta'' = -P cos(theta), theta(0) = 0,
    theta'(L) = 0. The first integral gives theta'^2 = (2 P / EI)(sin phi0 - sin theta)
    with phi0 = theta(L). The substitution 1 + sin(theta) = 2 k^2 sin(psi)^2 with
    k^2 = (1 + sin phi0) / 2 (k = sin(pi/4 + phi0/2)) turns ds = d theta / theta' into
    (L / sqrt(alpha)) d psi / sqrt(1 - k^2 sin(psi)^2), psi from beta = asin(1 / (k sqrt 2))
    to pi/2. Hence

        sqrt(alpha) = K(k) - F(beta, k)                      (fixes phi0)
        x(L) / L = 1 - 2 (E(k) - E(beta, k)) / sqrt(alpha)   (sin theta = 2 k^2 sin^2 psi - 1)
        z(L) / L = sqrt(2 sin(phi0) / alpha)                 (theta'(0) = P z(L) / EI)

    Returns (x(L)/L, z(L)/L, phi0). scipy's elliptic integrals take the parameter m = k^2.
    """

    def parts(phi0):
        m = 0.5 * (1.0 + np.sin(phi0))
        beta = np.arcsin(1.0 / np.sqrt(2.0 * m))
        return m, beta

    def gap(phi0):
        m, beta = parts(phi0)
        return special.ellipk(m) - special.ellipkinc(beta, m) - np.sqrt(alpha)

    # gap(0) = -sqrt(alpha) < 0 and gap -> +inf as phi0 -> pi/2 (K(1) diverges).
    phi0 = optimize.brentq(gap, 0.0, 0.5 * np.pi - 1e-14, xtol=1e-16, rtol=1e-15, maxiter=500)
    m, beta = parts(phi0)
    x = 1.0 - 2.0 * (special.ellipe(m) - special.ellipeinc(beta, m)) / np.sqrt(alpha)
    z = np.sqrt(2.0 * np.sin(phi0) / alpha)
    return x, z, phi0


def circular_arc(length, curvature):
    """Tip (x, z) of a rod clamped at the origin along +z bent to constant curvature toward
    +x (a pure end moment M about +y: curvature M / EI)."""
    r = 1.0 / curvature
    a = curvature * length
    return r * (1.0 - np.cos(a)), r * np.sin(a)


def beam_at(beam, s):
    """Row index of arc length s in a BeamSolution (the last row at that s: after a jump)."""
    ss = np.asarray(beam.s)
    i = np.flatnonzero(np.abs(ss - s) < 1e-9)
    assert i.size, f"s = {s} is not a solution point"
    return int(i[-1])


def segment_slices(beam, s0, s1):
    """Index ranges of the integration segments of a BeamSolution lying inside [s0, s1].

    Segment boundaries appear twice in beam.s (before and after the junction), so each
    segment is a maximal run of strictly increasing s.
    """
    ss = np.asarray(beam.s)
    breaks = np.flatnonzero(np.diff(ss) <= 0.0) + 1
    out = []
    for a, b in zip(np.r_[0, breaks], np.r_[breaks, ss.size]):
        if b - a >= 2 and ss[a] >= s0 - 1e-9 and ss[b - 1] <= s1 + 1e-9:
            out.append(slice(int(a), int(b)))
    return out


def integrate_position(beam, s0, s1):
    """Integral of the deformed centreline p(s) over [s0, s1], by the end-corrected
    trapezoidal rule on the solution's points: sum h/2 (p_i + p_i+1) - h^2/12 (p'(s1) -
    p'(s0)) on each segment, with the tangent p' = R v taken from the frame and the strain
    v = R^T n / (kGA, kGA, EA) + e3, which the caller folds in by passing `tangent`.
    Here we return (trapezoid sum, [(h, first index, last index), ...]) for the caller."""
    raise NotImplementedError
