"""One rod against closed-form solutions: the large-deflection elastica (Bisshopp-Drucker),
a pure end moment (circular arc), the integrator's order, and Timoshenko shear.

solve_cantilever clamps the rod at the origin along +z; a tip force (P, 0, 0) bends it
toward +x and a tip moment (0, M, 0) curls it toward +x.
"""

import jax
import numpy as np
import optimistix as optx
import pytest
from helpers import bisshopp_drucker, circular_arc

import finray_jax as fr

# The closed-form checks run under standard dtype promotion whatever conftest sets, so
# that they test the physics alone; test_cantilever_under_strict_promotion checks that
# solve_cantilever also runs under strict promotion.
standard_promotion = jax.numpy_dtype_promotion("standard")

# An effectively inextensible, unshearable rod: a thin band, L = 100 mm, t = 0.01 mm,
# d = 1 mm. Axial and shear strains are ~ alpha t^2 / (12 L^2) ~ 1e-9 alpha, and the shear
# deflection relative to bending is E t^2 / (4 k G L^2) = 7.8e-9, so the Cosserat rod
# matches the inextensible elastica to ~1e-8 relative; E = 1.2e7 MPa makes EI = 1 N mm^2.
L = 100.0
THIN = fr.Section(thickness=0.01, depth=1.0)
STEEL_LIKE = fr.Material(E=1.2e7, nu=0.3)
EI = 1.0


def _tip(sol):
    assert sol.result == optx.RESULTS.successful
    return np.asarray(sol.position[-1])


@pytest.mark.parametrize("alpha", [0.5, 1.0, 3.0, 10.0])
def test_bisshopp_drucker_reference_itself(alpha):
    """The closed form in helpers.py against an independent shooting solution of
    theta'' = -alpha cos(theta), theta(0) = 0, theta'(1) = 0 (L = EI = 1), integrated by
    scipy at rtol 1e-12; and at alpha = 1 against Bisshopp and Drucker's table
    (x/L = 0.3017, 1 - z/L = 0.0564)."""
    from scipy import integrate, optimize

    def rhs(s, y):  # y = (theta, theta', x, z)
        return [y[1], -alpha * np.cos(y[0]), np.sin(y[0]), np.cos(y[0])]

    def shoot(c):
        return integrate.solve_ivp(
            rhs, (0.0, 1.0), [0.0, c, 0.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-14
        ).y[:, -1]

    # theta'(0) = alpha z(L) lies in (0, alpha]; theta'(1) < 0 at 0 and >= 0 at alpha.
    c = optimize.brentq(lambda c: shoot(c)[1], 1e-9, alpha, xtol=1e-15)
    theta, _, x, z = shoot(c)
    xr, zr, phi0 = bisshopp_drucker(alpha)
    assert abs(xr - x) < 1e-9 and abs(zr - z) < 1e-9 and abs(phi0 - theta) < 1e-9
    if alpha == 1.0:
        assert round(xr, 4) == 0.3017 and round(1.0 - zr, 4) == 0.0564


@pytest.mark.parametrize("alpha", [0.25, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0])
def test_elastica_tip_force_planar(alpha):
    # The default discretisation (4 segments x 10 Tsit5 steps) is ~1e-10 accurate here;
    # the tolerance 1e-6 (relative) is 100x above the model's own 1e-8 departure from the
    # inextensible elastica.
    P = alpha * EI / L**2
    x, z, _ = bisshopp_drucker(alpha)
    with standard_promotion:
        tip = _tip(fr.solve_cantilever(L, STEEL_LIKE, THIN, tip_force=(P, 0.0, 0.0)))
    assert abs(tip[0] / L - x) < 1e-6 * x
    assert abs(tip[2] / L - z) < 1e-6 * z
    assert tip[1] == 0.0


@pytest.mark.parametrize("alpha", [1.0, 10.0])
def test_elastica_tip_force_spatial(alpha):
    P = alpha * EI / L**2
    x, z, _ = bisshopp_drucker(alpha)
    with standard_promotion:
        tip = _tip(
            fr.solve_cantilever(L, STEEL_LIKE, THIN, tip_force=(P, 0.0, 0.0), mode="spatial")
        )
    assert abs(tip[0] / L - x) < 1e-6 * x
    assert abs(tip[2] / L - z) < 1e-6 * z
    assert abs(tip[1]) < 1e-12 * L


@pytest.mark.parametrize("alpha", [1.0, 5.0])
def test_elastica_out_of_plane_square_section(alpha):
    """A square section bends alike about both axes: a force along +y gives the same
    elastica in the y-z plane (exercises the 3-D model's other bending axis)."""
    t = 0.01
    square = fr.Section(thickness=t, depth=t)
    material = fr.Material(E=12.0 / t**4, nu=0.3)  # EI = 1 N mm^2 about both axes
    P = alpha * EI / L**2
    x, z, _ = bisshopp_drucker(alpha)
    with standard_promotion:
        tip = _tip(
            fr.solve_cantilever(L, material, square, tip_force=(0.0, P, 0.0), mode="spatial")
        )
    assert abs(tip[1] / L - x) < 1e-6 * x
    assert abs(tip[2] / L - z) < 1e-6 * z
    assert abs(tip[0]) < 1e-12 * L


@pytest.mark.parametrize("mode", ["planar", "spatial"])
@pytest.mark.parametrize("turn", [0.5, np.pi, 2 * np.pi])
def test_pure_end_moment_gives_a_circular_arc(mode, turn):
    # M L / EI = turn: a circle of radius EI / M (no force, so no axial or shear strain:
    # only the integration error, observed <= 1e-11 L, remains). Tolerance 1e-6 L.
    M = turn * EI / L
    x, z = circular_arc(L, M / EI)
    with standard_promotion:
        sol = fr.solve_cantilever(L, STEEL_LIKE, THIN, tip_moment=(0.0, M, 0.0), mode=mode)
    tip = _tip(sol)
    assert abs(tip[0] - x) < 1e-6 * L
    assert abs(tip[2] - z) < 1e-6 * L
    # The moment is uniform along the rod, and the tangent turns by exactly M s / EI.
    np.testing.assert_allclose(np.asarray(sol.moment)[:, 1], M, rtol=1e-9)
    d3 = np.asarray(sol.frame)[:, :, 2]
    angle = np.unwrap(np.arctan2(d3[:, 0], d3[:, 2]))
    np.testing.assert_allclose(angle, M * np.asarray(sol.s) / EI, atol=1e-6)


def test_tsit5_converges_at_fifth_order():
    """Tip error of one segment at n = 2, 4, 8 Tsit5 steps against n = 64: slope ~5."""
    alpha = 2.0  # tip rotation ~0.9 rad; n = 2 is already in the asymptotic range
    P = alpha * EI / L**2

    def tip(n):
        with standard_promotion:
            return _tip(
                fr.solve_cantilever(
                    L,
                    STEEL_LIKE,
                    THIN,
                    tip_force=(P, 0.0, 0.0),
                    segments=1,
                    integrator=fr.Integrator(steps=n),
                )
            )

    ref = tip(64)  # its own error is ~(8/64)^5 = 3e-5 of the n = 8 error
    ns = [2, 4, 8]
    err = np.array([np.linalg.norm(tip(n) - ref) for n in ns])
    assert np.all(err > 1e-12 * L), err  # well above the Newton tolerance and rounding
    slope = -np.polyfit(np.log(ns), np.log(err), 1)[0]
    assert slope > 4.0, (err, slope)


def test_timoshenko_shear_deflection():
    """A short thick cantilever: shear adds P L / (k G A) to P L^3 / (3 EI)."""
    length, t, d = 10.0, 4.0, 2.0
    material = fr.Material(E=1000.0, nu=0.3, shear_coefficient=5.0 / 6.0)
    ei = 1000.0 * d * t**3 / 12.0
    kga = 5.0 / 6.0 * material.G * t * d
    alpha = 1e-3  # P L^2 / EI: geometric nonlinearity ~ 0.1 alpha^2 = 1e-7 relative
    P = alpha * ei / length**2
    expected = P * length**3 / (3.0 * ei) + P * length / float(kga)
    shear_part = P * length / float(kga) / expected
    assert shear_part > 0.1  # the test would see a wrong k or a missing shear term
    with standard_promotion:
        tip = _tip(fr.solve_cantilever(length, material, fr.Section(t, d), tip_force=(P, 0.0, 0.0)))
    # 1e-5: 100x the nonlinear correction; a 1 % error in the shear term is 1e-3.
    assert abs(tip[0] - expected) < 1e-5 * expected
    assert abs(tip[1]) == 0.0


def test_cantilever_under_strict_promotion():
    """solve_cantilever must run under strict dtype promotion (house style)."""
    # One segment of two steps keeps the extra (strict-mode) compilation small.
    with jax.numpy_dtype_promotion("strict"):
        sol = fr.solve_cantilever(
            L,
            STEEL_LIKE,
            THIN,
            tip_force=(1e-4, 0.0, 0.0),
            segments=1,
            integrator=fr.Integrator(steps=2),
        )
    assert sol.result == optx.RESULTS.successful
    assert sol.s.dtype == np.float64


def test_tapered_cantilever_matches_linear_theory():
    """A linearly tapered cantilever (3 -> 1.5 mm) under a tiny tip force: the tip equals
    linear Timoshenko theory, integral of P (L-x)^2 / EI(x) + P / kGA(x), computed here by
    quadrature. The load is small (deflection 1e-4 L), so the nonlinear part is ~1e-8:
    tolerance 1e-6 relative. The rod model samples the section at 4 points per segment and
    interpolates cubically, which is exact for A and I of a linear thickness profile."""
    from scipy.integrate import quad

    E, nu, k = 12.0, 0.45, 5.0 / 6.0
    L, d, t0, t1, P = 100.0, 20.0, 3.0, 1.5, 1e-5
    G = E / (2 * (1 + nu))
    sol = fr.solve_cantilever(
        L, fr.Material(E, nu, k), fr.Section(t0, d, tip_thickness=t1), tip_force=(P, 0, 0)
    )
    t = lambda x: t0 + (t1 - t0) * x / L
    bend = quad(lambda x: P * (L - x) ** 2 / (E * d * t(x) ** 3 / 12), 0, L, epsrel=1e-13)[0]
    shear = quad(lambda x: P / (k * G * d * t(x)), 0, L, epsrel=1e-13)[0]
    assert abs(float(sol.position[-1, 0]) / (bend + shear) - 1.0) < 1e-6


def test_taper_with_equal_ends_equals_constant_section():
    m = fr.Material(12.0, 0.45)
    a = fr.solve_cantilever(100.0, m, fr.Section(3.0, 20.0), tip_force=(1e-3, 0, 0))
    b = fr.solve_cantilever(
        100.0, m, fr.Section(3.0, 20.0, tip_thickness=3.0), tip_force=(1e-3, 0, 0)
    )
    np.testing.assert_allclose(np.asarray(a.position), np.asarray(b.position), atol=1e-12)
