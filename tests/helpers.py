"""Closed-form references and balance checks shared by the tests (no finray_jax internals)."""

import equinox as eqx
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
    """Row index of arc length s in a BeamSolution (the last row at that s, i.e. after the
    jump when s is a cut; positions are continuous across a cut)."""
    ss = np.asarray(beam.s)
    i = np.flatnonzero(np.abs(ss - s) < 1e-9)
    assert i.size, f"s = {s} is not a solution point"
    return int(i[-1])


def segment_slices(beam, s0, s1):
    """Row ranges of the integration segments of a BeamSolution lying inside [s0, s1].

    Cuts appear twice in beam.s (before and after the junction), so each segment is a
    maximal run of strictly increasing s.
    """
    ss = np.asarray(beam.s)
    breaks = np.flatnonzero(np.diff(ss) <= 0.0) + 1
    out = []
    for a, b in zip(np.r_[0, breaks], np.r_[breaks, ss.size]):
        if b - a >= 2 and ss[a] >= s0 - 1e-9 and ss[b - 1] <= s1 + 1e-9:
            out.append(slice(int(a), int(b)))
    return out


def newton_cotes_weights(n):
    """Weights of the closed (n + 1)-point Newton-Cotes rule on [0, 1] (exact for
    polynomials of degree n)."""
    x = np.linspace(0.0, 1.0, n + 1)
    return np.linalg.solve(np.vander(x, increasing=True).T, 1.0 / np.arange(1, n + 2))


def integrate_position(beam, s0, s1):
    """Integral of the deformed centreline p(s) over [s0, s1].

    Each integration segment of the solution is sampled at equal steps; p(s) is smooth
    (analytic) inside a segment, so the closed Newton-Cotes rule through all its points
    (degree 10 for the default 10 steps) is accurate far beyond the trapezoidal rule.
    """
    ss, pos = np.asarray(beam.s), np.asarray(beam.position)
    total, covered = np.zeros(3), 0.0
    for sl in segment_slices(beam, s0, s1):
        s, p = ss[sl], pos[sl]
        h = np.diff(s)
        assert np.allclose(h, h[0], rtol=1e-9, atol=0), "steps are not equal"
        total += (s[-1] - s[0]) * newton_cotes_weights(len(s) - 1) @ p
        covered += s[-1] - s[0]
    assert abs(covered - (s1 - s0)) < 1e-9, f"segments cover {covered}, not {s1 - s0}"
    return total


def load_beam(sol, beam):
    """The BeamSolution of beam index `beam` (0 front, 1 back, 2 + i crossbeam i)."""
    if beam == 0:
        return sol.front
    if beam == 1:
        return sol.back
    return sol.crossbeam(beam - 2)


def global_balance(finger, sol, load_factor=1.0):
    """Sum of all external forces and of their moments about the origin on the whole finger.

    External: both base reactions (force the adaptor applies, moment about the beam's base
    point, which is the beam's first solution point) and the applied loads times
    load_factor, acting at their DEFORMED points. Returns (force (3,), moment (3,),
    largest moment term) in N and N mm.
    """
    # Imported here so this module stays free of finray_jax at import time.
    from finray_jax import DistributedLoad, PointLoad

    forces, moments = [], []
    for beam, reaction in ((sol.front, sol.reactions_front), (sol.back, sol.reactions_back)):
        F, M = np.asarray(reaction.force), np.asarray(reaction.moment)
        forces.append(F)
        moments += [M, np.cross(np.asarray(beam.position[0]), F)]
    for load in finger.loads:
        bs = load_beam(sol, load.beam)
        if isinstance(load, PointLoad):
            F = load_factor * np.asarray(load.force)
            p = np.asarray(bs.position[beam_at(bs, float(load.s))])
            forces.append(F)
            moments += [np.cross(p, F), load_factor * np.asarray(load.moment)]
        elif isinstance(load, DistributedLoad):
            s0, s1 = (float(x) for x in load.s_range)
            f = load_factor * np.asarray(load.force_per_length)
            forces.append(load_factor * np.asarray(load.total_force))
            moments.append(np.cross(integrate_position(bs, s0, s1), f))
        else:
            raise TypeError(load)
    scale = max(np.max(np.abs(m)) for m in moments)
    return np.sum(forces, axis=0), np.sum(moments, axis=0), scale


def round_trip_finger(**changes):
    """test_toml's round-trip finger: tapered front beam, curved back beam, three uneven
    crossbeams (valid; `changes` replace Finger fields)."""
    import finray_jax as fr

    kw = dict(
        material=fr.Material(20.0, 0.3, shear_coefficient=1.0),
        front_base=(1.0, -2.0),
        back_base=(35.5, 0.25),
        tip=(3.0, 90.0),
        front=fr.Section(2.0, 15.0, tip_thickness=1.25),
        back=fr.Section(1.75, 15.0),
        crossbeams=fr.Crossbeams(
            [10.0, 40.1, 70.0], [11.0, 45.0, 80.0], [1.0, 1.1, 0.9], [15.0, 14.0, 13.0]
        ),
        back_curvature=-0.002,
    )
    kw.update(changes)
    return fr.Finger(**kw)


def without_jacobian(sol):
    """The Solution without its Jacobian factors (a warm start from it is then one from its
    deformation alone)."""
    return eqx.tree_at(lambda s: s.jacobian, sol, None, is_leaf=lambda x: x is None)


def contact_wrench(finger, sol, load_factor=1.0, beams=(0, 1)):
    """Total force and moment about the origin that the objects and the support apply to
    the finger's main beams (those in `beams`: 0 front, 1 back), from the solution alone
    (not from the contact law).

    Within a segment only contact and distributed loads act (point loads, crossbeams and
    the tip junction act at cuts), and n' = -f, (m + p x n)' = -(l + p x f) there. So on
    each segment block (its start row, then its flexible part) the external wrench is
    -(n) and -(m + p x n) from the block's first row to its last; the distributed loads'
    share is taken off. Returns (force (3,), moment (3,)) in N and N mm.
    """
    from finray_jax import DistributedLoad

    force, moment = np.zeros(3), np.zeros(3)
    for b, beam in ((0, sol.front), (1, sol.back)):
        if b not in beams:
            continue
        rows = sol.steps + 2
        p = np.asarray(beam.position).reshape(-1, rows, 3)
        n = np.asarray(beam.force).reshape(-1, rows, 3)
        m = np.asarray(beam.moment).reshape(-1, rows, 3)
        invariant = m + np.cross(p, n)
        force -= np.sum(n[:, -1] - n[:, 0], axis=0)
        moment -= np.sum(invariant[:, -1] - invariant[:, 0], axis=0)
        for load in finger.loads:
            if isinstance(load, DistributedLoad) and load.beam == b:
                s0, s1 = (float(x) for x in load.s_range)
                f = load_factor * np.asarray(load.force_per_length)
                force -= load_factor * np.asarray(load.total_force)
                moment -= np.cross(integrate_position(beam, s0, s1), f)
    return force, moment


def wrapped_cantilever(P, EI, L, Rc):
    """Inextensible elastica of a cantilever wrapping a rigid cylinder (frictionless)
    under a dead tip force P perpendicular to its undeformed axis.

    The rod is clamped along +z at the origin, where it touches the cylinder, whose
    centreline radius (cylinder radius plus half the rod's thickness) is Rc and whose
    centre is at (Rc, 0); the force is +x, toward the cylinder. With theta(s) the tangent
    angle from +z toward +x, the rod wraps the cylinder from s = 0 to the lift-off
    s = a = Rc phi (there its curvature is 1/Rc, its moment EI / Rc) and is a free
    elastica from a to L: EI theta' = P (z(L) - z(s)), so as in `bisshopp_drucker`
    theta'^2 = (2 P / EI)(sin phi0 - sin theta), phi0 = theta(L). Moment continuity at
    the lift-off, theta'(a) = 1 / Rc, gives sin phi0 = sin phi + EI / (2 P Rc^2). With
    1 + sin(theta) = 2 k^2 sin(psi)^2, k^2 = (1 + sin phi0) / 2, c = sqrt(EI / P):

        L - Rc phi = c (K(k) - F(beta, k)),  sin(beta)^2 = (1 + sin phi) / (2 k^2)
        x(L) = Rc (1 - cos phi) + (L - Rc phi) - 2 c (E(k) - E(beta, k))
        z(L) = Rc sin phi + EI / (P Rc)          (theta'(a) = P (z(L) - z(a)) / EI)

    The first fixes phi. Returns (phi, phi0, x(L), z(L)), or None when P is too small
    for the rod to touch beyond its clamp (its curvature at the clamp stays below 1/Rc).
    In a frictionless wrap the rod's tension is constant, P sin(phi) >= 0: the wrap
    stays below 90 degrees however large P is.
    """
    c = np.sqrt(EI / P)
    lift = EI / (2.0 * P * Rc**2)

    def parts(phi):
        m = 0.5 * (1.0 + np.sin(phi) + lift)
        beta = np.arcsin(np.sqrt(0.5 * (1.0 + np.sin(phi)) / m))
        return m, beta

    def gap(phi):
        m, beta = parts(phi)
        return L - Rc * phi - c * (special.ellipk(m) - special.ellipkinc(beta, m))

    if lift >= 1.0 or gap(0.0) <= 0.0:
        return None
    phi = optimize.brentq(gap, 0.0, np.arcsin(1.0 - lift), xtol=1e-15, rtol=1e-15)
    m, beta = parts(phi)
    x = Rc * (1.0 - np.cos(phi)) + (L - Rc * phi)
    x -= 2.0 * c * (special.ellipe(m) - special.ellipeinc(beta, m))
    z = Rc * np.sin(phi) + EI / (P * Rc)
    return phi, np.arcsin(np.sin(phi) + lift), x, z
