"""Gradients of scalar outputs with respect to every continuous design value, through the
root solve (implicit function theorem), in `jax.jacfwd` and `jax.grad`, against central
finite differences; the differentiable limit (fold) load factor; design values that never
recompile.

tests/test_design.py already checks tip.dx, reaction.front.fx and max_strain on ref-A
under L1 for 13 design values (one index of each crossbeam array). Here:

* Finger-1 (examples/finger1.toml, 4 N over l5..l7) with its back beam clamped over
  l_c = 10 mm: tip.dx, tip.dz, both base reactions and max_strain with respect to l_c,
  front_s, back_s, angle and thickness of EVERY crossbeam, both main-beam thicknesses,
  depth, E and tip.x (slow: ~3 min of compilation; the default suite's
  tests/test_design.py covers every kind of design value on ref-A).
* ref-A under L2 (1.5 N, strongly nonlinear: reached by load continuation) with l_c = 8
  mm, the same list (slow).
* The limit load factor of ref-A under L2 and L3 (slow: the continuation compiles).

Each case builds ONE jitted program of a vector of design values that returns both the
`jax.jacfwd` Jacobian and the `jax.grad` rows (one compile instead of two); finite
differences come from eager solves of the same design function.

Crossbeam angles are applied after back_s by `set_design` (they move back_s), so back_s
is varied by a second `set_design` on top: x = (values..., increments of back_s[i]). The
derivative with respect to increment i is the derivative with respect to back_s[i] with
everything else held; the one with respect to angle[i] moves back_s[i] along the beam.
"""

import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import finray_jax as fr
from finray_jax import _fold, _solve, design
from finray_jax.io import load_finger

ROOT = pathlib.Path(__file__).resolve().parents[1]

OUTS = ["tip.dx", "tip.dz", "reaction.front.fx", "reaction.back.my", "max_strain"]
C = 7  # crossbeams of both fingers
PER_CB = ["front_s", "angle", "thickness"]
COMMON = [f"crossbeams.{k}[{i}]" for k in PER_CB for i in range(C)]
COMMON += ["front.thickness", "back.thickness", "depth", "material.E", "tip.x"]
COMMON = ["adaptor.back_clamp_length"] + COMMON
BACK_S = [f"crossbeams.back_s[{i}]" for i in range(C)]
LABELS = COMMON + BACK_S


def _finger1():
    finger, _ = load_finger(ROOT / "examples" / "finger1.toml")
    return finger


class Case:
    """A base finger and the design function x -> finger of the gradient tests."""

    def __init__(self, base: fr.Finger, init=None):
        self.base = base
        self.topo = fr.topology_of(base, "planar")
        self.init = init  # a solution to warm start from (ref-A L2: on its branch)
        x = design.get_design(base, COMMON)
        self.x0 = np.concatenate([[float(x[k]) for k in COMMON], np.zeros(C)])

    def finger(self, x):
        f = design.set_design(self.base, dict(zip(COMMON, x[: len(COMMON)])))
        back_s = f.crossbeams.back_s + x[len(COMMON) :]
        return design.set_design(f, {"crossbeams.back_s": back_s})

    def outputs(self, x):
        f = self.finger(x)
        sol = fr.solve_finger(f, mode="planar", topology=self.topo, init=self.init)
        out = design.evaluate_outputs(sol, f, OUTS)
        return jnp.stack([out[k] for k in OUTS])

    def eager(self, x):
        """Outputs of an eager solve, and where max_strain is attained (beam, s)."""
        f = self.finger(x)
        sol = fr.solve_finger(f, mode="planar", topology=self.topo, init=self.init)
        assert sol.status == "converged", sol.status
        out = design.evaluate_outputs(sol, f, OUTS)
        return np.array([float(out[k]) for k in OUTS]), _argmax_strain(sol, f)


def _argmax_strain(sol, finger):
    """(beam, index of the solution point) where max_strain is attained. (Points move with
    the design, e.g. the clamp exit with l_c; their index does not.)"""
    best = None
    for beam in (0, 1):
        e = np.asarray(design.main_beam_strain(sol, finger, beam))
        i = int(np.argmax(e))
        if best is None or e[i] > best[0]:
            best = (e[i], beam, i)
    return best[1:]


def _steps(case: Case):
    """Finite-difference steps h: 1e-3 relative for lengths (back_s increments relative to
    the back_s they move), thicknesses and E, and 1e-3 rad for angles. Measured on ref-A
    L2: plain central differences at h = 1e-4 are off by 1.1e-5 (angle[0], falling as
    h^2: truncation), and tip.dx / back_s[6], whose derivative is ~1e-7 of the largest in
    its row, cannot get below ~2e-5 with steps of 1e-3 mm or less (solve noise ~1e-13 over
    2h grows as h shrinks); relative steps with extrapolation (see `_fd`) avoid both."""
    scale = np.maximum(np.abs(case.x0), 1.0)
    scale[len(COMMON) :] = np.asarray(case.base.crossbeams.back_s)
    return 1e-3 * scale


def _fd(f, x0, e, levels):
    """Central differences D(k h) at the step multiples `levels` (descending by halves; e
    = h times a unit vector), each adjacent pair combined by Richardson extrapolation,
    (4 D(k h / 2) - D(k h)) / 3 (truncation O(h^4)). Per output, Ridders' choice: going
    down from the largest step, each estimate's error is the larger of its gaps to its
    neighbours, and the estimate of least error is kept, stopping where the error has
    grown past twice the least (the steps have entered the solve's noise). It balances
    truncation, which grows with the step, against solve noise, which grows as it
    shrinks. (Chosen over all the estimates at once, the smallest steps' pair could win by
    chance: on ref-A L2 tip.dx / angle[6] R(h) and R(2 h) agree to 3e-11 while both are
    off by ~1e-5, which fails the test.) Measured on ref-A
    L2: tip.dx / angle[6] (-1.03e-5 mm/rad, ~1e-6 of the largest in its row) is 1e-14 mm
    of round-off in tip.dx (~5e-16 relative) away from the implicit derivative at each
    solve, which over 2 h = 2e-3 rad is 5e-6 relative: Richardson estimates from steps of
    1e-3 rad or less are off by 2.8e-6 to 8.5e-6 (they move with the warm start), those
    from 4e-3 to 16e-3 rad by 2.8e-7 to 1.1e-6. angle[0] needs the small steps (its
    truncation is larger). Returns (h times the estimate, where): the max-strain locations
    of the solves at h and h / 2."""
    pts = {k: (f(x0 + k * e), f(x0 - k * e)) for k in levels}
    D = {k: (p[0][0] - p[1][0]) / (2 * k) for k, p in pts.items()}
    R = np.stack([(4.0 * D[k / 2] - D[k]) / 3.0 for k in levels[:-1]])
    where = tuple(w for k in (1.0, 0.5) for _, w in pts[k])
    if len(R) == 1:
        return R[0], where
    gap = np.abs(np.diff(R, axis=0))  # |R_(j+1) - R_j|
    err = np.maximum(np.vstack([gap[:1], gap]), np.vstack([gap, gap[-1:]]))
    pick = np.zeros(R.shape[1], int)
    for col in range(R.shape[1]):
        for j in range(1, R.shape[0]):
            if err[j, col] > 2.0 * err[pick[col], col]:
                break
            if err[j, col] < err[pick[col], col]:
                pick[col] = j
    return R[pick, np.arange(R.shape[1])], where


def _levels(case: Case, e):
    """Step multiples for `_fd`: down from 16 h where the design keeps its topology at +-16
    h, from 4 h where it does at +-4 h, else h and h / 2 only."""
    for top in (16.0, 4.0):
        if all(
            bool(design.design_valid(case.finger(case.x0 + s * e), case.topo)) for s in (top, -top)
        ):
            return tuple(top / 2**j for j in range(int(np.log2(top)) + 2))
    return (1.0, 0.5)


def derivatives(case: Case):
    x0 = jnp.asarray(case.x0)
    W = jnp.eye(len(OUTS))

    def both(x, W):
        jac = jax.jacfwd(case.outputs)(x)
        rows = jax.vmap(jax.grad(lambda x, w: jnp.dot(w, case.outputs(x))), in_axes=(None, 0))(x, W)
        return jac, rows

    jac, rows = (np.asarray(a) for a in jax.jit(both)(x0, W))
    out0, where0 = case.eager(case.x0)
    fd = np.zeros_like(jac)
    moved = []  # design values whose FD solves moved the location of max_strain
    one_sided = {}  # design values at a tie of events (see below): the side used
    for i, h in enumerate(_steps(case)):
        e = np.zeros_like(case.x0)
        e[i] = h
        valid = [
            bool(design.design_valid(case.finger(case.x0 + s * e), case.topo)) for s in (1, -1)
        ]
        if all(valid):
            fd[:, i], where = _fd(case.eager, case.x0, e, _levels(case, e))
            fd[:, i] /= h
        else:
            # An attachment that ties with another event (Finger-1's crossbeams 4 and 6
            # sit at the ends of the distributed load, s = 75 and 105) is a switch of the
            # topology: moving it one way reorders the events. The derivative there is
            # the one-sided derivative on the side that keeps the topology; compare with
            # the second-order one-sided difference D(h) = (-3 f0 + 4 f(h) - f(2h)) / (2h)
            # at h and h / 2, h a tenth of the central step, extrapolated (4 D(h/2) -
            # D(h)) / 3. Measured for tip.dx / front_s[4] (~3e-3 of the largest in its
            # row): D alone is off by 8e-5 relative at h, 2e-5 at h / 2 and 3e-6 at h / 4
            # (O(h^2)); the extrapolation by 4e-7.
            assert any(valid), LABELS[i]
            sign = 1.0 if valid[0] else -1.0
            h, e = 0.1 * h, 0.1 * e
            D, where = [], ()
            for k in (1.0, 0.5):
                (f1, w1), (f2, w2) = (case.eager(case.x0 + m * k * sign * e) for m in (1, 2))
                D.append((-3.0 * out0 + 4.0 * f1 - f2) / (2 * sign * k * h))
                where += (w1, w2)
            fd[:, i] = (4.0 * D[1] - D[0]) / 3.0
            one_sided[LABELS[i]] = sign
        if any(w != where0 for w in where):
            moved.append(LABELS[i])
    return dict(
        jac=jac, rows=rows, fd=fd, out0=out0, where=where0, moved=moved, one_sided=one_sided
    )


def _rel(a, b):
    return np.abs(a - b) / np.abs(b)


def _check_against_fd(d, which, k):
    """Relative error < 1e-5 for every design value away from a switch of the topology
    (the tied attachments are checked apart, see test_finger1_ties_match_one_sided_fd)."""
    keep = np.array([n not in d["one_sided"] for n in LABELS])
    got, fd = d[which][k][keep], d["fd"][k][keep]
    names = [n for n, kept in zip(LABELS, keep) if kept]
    # Every design value matters to every output here (a zero would hide a broken
    # derivative); reaction.back.my has no exactly vanishing entry either.
    assert np.all(np.abs(fd) > 0), dict(zip(names, fd))
    err = _rel(got, fd)
    assert np.all(err < 1e-5), {n: f"{e:.1e}" for n, e in zip(names, err) if e >= 1e-5}


# --------------------------------------------------------------------------------------
# Finger-1 with a partly clamped back beam (default suite)
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def finger1_derivs():
    base = design.set_design(_finger1(), {"adaptor.back_clamp_length": 10.0})
    return derivatives(Case(base))


@pytest.mark.slow
@pytest.mark.extended
def test_finger1_max_strain_is_at_a_unique_point(finger1_derivs):
    """max_strain is a max over solution points: its derivative is that of the strain at
    the maximising point, valid while that point does not change. None of the +-h solves
    moved it (points duplicated at a cut hold the same state and tie harmlessly)."""
    assert finger1_derivs["moved"] == []


@pytest.mark.slow
@pytest.mark.extended
def test_finger1_ties_are_one_sided(finger1_derivs):
    """Crossbeam 4 ends where the load starts (s = 75; the topology puts the crossbeam
    first) and crossbeam 6 where it ends (s = 105; the load's end first): only moving
    crossbeam 4 toward the base, and crossbeam 6 toward the tip, keeps the topology."""
    assert finger1_derivs["one_sided"] == {
        "crossbeams.front_s[4]": -1.0,
        "crossbeams.front_s[6]": 1.0,
    }


def test_zero_length_segment_has_no_rigid_part_in_its_derivative():
    """Finger-1's crossbeam 4 ends where the distributed load starts (s = 75): the front
    segment between the two events has zero length. Moving the crossbeam toward the base
    lengthens it, and nothing of the front beam is clamped, so the derivative of every
    front segment's rigid part is zero (jnp.clip's min at the tie gave -0.5 there)."""
    base = _finger1()
    topo = fr.topology_of(base, "planar")
    name = "crossbeams.front_s[4]"
    s4 = design.get_design(base, [name])[name]

    def table(s):
        finger = design.set_design(base, {name: s})
        return _solve.make_problem(topo, fr.Integrator(), finger).table

    t, dt = jax.jvp(table, (jnp.asarray(s4),), (jnp.ones(()),))
    zero = np.flatnonzero(np.asarray(t.length) == 0.0)  # (crossbeam 6 ties at s = 105)
    moved = zero[np.asarray(dt.length)[zero] != 0.0]
    assert moved.size == 1 and float(t.start_s[moved[0]]) == 75.0, np.asarray(t.length)
    assert float(dt.length[moved[0]]) == -1.0
    # (no segment's clamped part depends on a front attachment)
    np.testing.assert_array_equal(np.asarray(dt.rigid), 0.0)


@pytest.mark.slow
@pytest.mark.extended
def test_finger1_ties_match_one_sided_fd(finger1_derivs):
    """At a tie the derivative is the one-sided one on the topology-keeping side. (The
    zero-length segment between the tied events has no rigid part on either side: a
    rigid part written as jnp.clip(..., 0, length) would pass half of d(length) into it
    through the tie of its min, and jacfwd would be far off here.)"""
    d = finger1_derivs
    idx = [LABELS.index(n) for n in d["one_sided"]]
    err = _rel(d["jac"][:, idx], d["fd"][:, idx])
    assert np.all(err < 1e-5), err


@pytest.mark.slow
@pytest.mark.extended
@pytest.mark.parametrize("k", range(len(OUTS)), ids=OUTS)
def test_finger1_jacfwd_matches_finite_differences(finger1_derivs, k):
    _check_against_fd(finger1_derivs, "jac", k)


@pytest.mark.slow
@pytest.mark.extended
@pytest.mark.parametrize("k", range(len(OUTS)), ids=OUTS)
def test_finger1_grad_matches_finite_differences(finger1_derivs, k):
    _check_against_fd(finger1_derivs, "rows", k)


@pytest.mark.slow
@pytest.mark.extended
def test_finger1_grad_equals_jacfwd(finger1_derivs):
    """Forward and reverse mode solve the same linear system (J and its transpose): they
    agree to rounding, far tighter than the finite differences."""
    jac, rows = finger1_derivs["jac"], finger1_derivs["rows"]
    scale = np.max(np.abs(jac), axis=1, keepdims=True)
    assert np.max(np.abs(rows - jac) / scale) < 1e-10


# --------------------------------------------------------------------------------------
# ref-A under L2: 1.5 N at s = 60, past the range of the direct Newton solve (slow)
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ref_a_l2_derivs():
    base = design.set_design(fr.ref_finger_a("L2"), {"adaptor.back_clamp_length": 8.0})
    sol = fr.solve_finger(base, mode="planar")
    assert sol.status == "converged"
    # Warm started from the loading-branch solution, every solve (traced and eager) is a
    # direct Newton solve accepted only on that branch (same sign of det J).
    return derivatives(Case(base, init=sol))


@pytest.mark.slow
@pytest.mark.extended
def test_ref_a_l2_max_strain_is_at_a_unique_point(ref_a_l2_derivs):
    assert ref_a_l2_derivs["moved"] == []


@pytest.mark.slow
@pytest.mark.extended
@pytest.mark.parametrize("which", ["jac", "rows"], ids=["jacfwd", "grad"])
@pytest.mark.parametrize("k", range(len(OUTS)), ids=OUTS)
def test_ref_a_l2_matches_finite_differences(ref_a_l2_derivs, which, k):
    _check_against_fd(ref_a_l2_derivs, which, k)


@pytest.mark.slow
@pytest.mark.extended
def test_ref_a_l2_grad_equals_jacfwd(ref_a_l2_derivs):
    jac, rows = ref_a_l2_derivs["jac"], ref_a_l2_derivs["rows"]
    scale = np.max(np.abs(jac), axis=1, keepdims=True)
    assert np.max(np.abs(rows - jac) / scale) < 1e-10


# --------------------------------------------------------------------------------------
# The limit (fold) load factor (slow: `limit_load`'s continuation compiles per topology)
# --------------------------------------------------------------------------------------

FOLD_NAMES = [
    "material.E",
    "front.thickness",
    "crossbeams.front_s[2]",
    "adaptor.back_clamp_length",
    "crossbeams.thickness[4]",
]


def fold_derivatives(load):
    base = design.set_design(fr.ref_finger_a(load), {"adaptor.back_clamp_length": 8.0})
    topo = fr.topology_of(base, "planar")
    lim = fr.limit_load(base, mode="planar")
    assert lim.found
    fold = _fold.fold_point(base, init=lim, topology=topo)
    assert bool(fold.converged)

    # x = (design values..., a factor on every load)
    def finger(x):
        f = design.set_design(base, dict(zip(FOLD_NAMES, x[:-1])))
        return f.scale_loads(x[-1])

    def factor(x):
        return _fold.limit_load_factor(finger(x), init=fold, topology=topo)

    x0 = np.array([float(v) for v in design.get_design(base, FOLD_NAMES).values()] + [1.0])

    def both(x):
        return jax.jacfwd(factor)(x), jax.grad(factor)(x), factor(x)

    jac, grad, lam = (np.asarray(a) for a in jax.jit(both)(jnp.asarray(x0)))
    # Central differences of the refined fold, in two step sizes for a Richardson estimate:
    # each perturbed fold is refined from the base fold (no continuation).
    hs = 1e-3 * np.maximum(np.abs(x0), 1.0)
    fd = np.zeros((2, len(x0)))
    for j, scale in enumerate((1.0, 0.5)):
        for i, h in enumerate(hs * scale):
            e = np.zeros_like(x0)
            e[i] = h
            fd[j, i] = (float(factor(x0 + e)) - float(factor(x0 - e))) / (2 * h)
    return dict(
        lim=lim, fold=fold, x0=x0, jac=jac, grad=grad, lam=float(lam), fd=fd,
        richardson=(4.0 * fd[1] - fd[0]) / 3.0,
    )  # fmt: skip


@pytest.fixture(
    scope="module",
    params=["L2", "L3"],
)
def fold_derivs(request):
    return fold_derivatives(request.param)


@pytest.mark.slow
def test_fold_is_refined(fold_derivs):
    """The refined point is a fold: R = 0, J singular, dlam/deta = 0; limit_load's
    continuation stops on the branch just before it (refined to ~min_arc_step^2)."""
    fold, lim = fold_derivs["fold"], fold_derivs["lim"]
    assert float(fold.max_residual) < 1e-10
    assert float(fold.singular_ratio) < 1e-12
    lam, lam_lim = float(fold.load_factor), float(lim.load_factor)
    assert lam_lim <= lam * (1 + 1e-14)
    assert lam - lam_lim < 1e-5 * lam
    assert fold_derivs["lam"] == pytest.approx(lam, rel=1e-12)


@pytest.mark.slow
def test_fold_scales_with_E_and_the_loads(fold_derivs):
    """Closed form: the equilibrium equations depend on E and the load only through
    lam F / E (for a fixed geometry), so lam* is proportional to E and inversely
    proportional to the load: d ln lam* / d ln E = 1 and d ln lam* / d ln F = -1."""
    x0, lam = fold_derivs["x0"], fold_derivs["lam"]
    for d in (fold_derivs["jac"], fold_derivs["grad"]):
        assert d[0] * x0[0] / lam == pytest.approx(1.0, abs=1e-9)
        assert d[-1] * x0[-1] / lam == pytest.approx(-1.0, abs=1e-9)


@pytest.mark.slow
def test_fold_gradient_matches_finite_differences(fold_derivs):
    jac, grad, rich = fold_derivs["jac"], fold_derivs["grad"], fold_derivs["richardson"]
    assert np.all(np.abs(rich) > 0)
    np.testing.assert_allclose(grad, jac, rtol=1e-10)
    err = _rel(jac, rich)
    assert np.all(err < 1e-5), dict(zip(FOLD_NAMES + ["load"], err))


# --------------------------------------------------------------------------------------
# A load gradient (the distributed force's parameter columns carry a tangent)
# --------------------------------------------------------------------------------------


def test_load_and_modulus_gradient_with_a_distributed_load():
    """The implicit rule differentiates the segments only in the parameter columns that
    carry a tangent; a design gradient leaves the distributed force out, a load gradient
    needs it. ref-A L3 (1 N spread over an arc), x = (E, factor on the load): tip dx and
    the front base reaction fx by jacfwd and grad, against finite differences and against
    the closed form: the equilibrium depends on E and the load only through lam F / E, so
    E du/dE = -lam du/dlam for the tip displacement u."""
    base = fr.ref_finger_a("L3")
    topo = fr.topology_of(base, "planar")

    def outputs(x):
        f = eqx.tree_at(lambda f: f.material.E, base, x[0]).scale_loads(x[1])
        sol = fr.solve_finger(f, topology=topo)
        return jnp.stack([sol.tip.displacement[0], sol.reactions_front.force[0]])

    x0 = np.array([float(base.material.E), 1.0])
    jac, grad = jax.jit(lambda x: (jax.jacfwd(outputs)(x), jax.grad(lambda x: outputs(x)[0])(x)))(
        jnp.asarray(x0)
    )
    jac, grad = np.asarray(jac), np.asarray(grad)
    np.testing.assert_allclose(grad, jac[0], rtol=1e-10)
    # closed form for the tip displacement
    assert x0[0] * jac[0, 0] == pytest.approx(-x0[1] * jac[0, 1], rel=1e-9)
    assert abs(jac[0, 1]) > 1.0  # the tip moves by millimetres per unit load factor
    f = lambda x: (np.asarray(outputs(jnp.asarray(x))), None)
    for i, h in enumerate((1e-3 * x0[0], 1e-3)):
        e = np.zeros(2)
        e[i] = h
        fd, _ = _fd(f, x0, e, levels=(4.0, 2.0, 1.0, 0.5))
        err = _rel(jac[:, i], fd / h)
        assert np.all(err < 1e-5), (i, jac[:, i], fd / h)


# --------------------------------------------------------------------------------------
# New design values never recompile
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_design_values_never_recompile():
    """Finger-1 on the modified adaptor (back beam clamped over 10 mm, rigid support to
    l_s = 60 mm) pushed onto its support: after one solve (compiling the traced solve with
    contact: ~1.5 min, hence slow), a solve of any other value of
    any design value compiles nothing and traces nothing."""
    base = eqx.tree_at(
        lambda f: f.adaptor, _finger1(), fr.Adaptor(back_clamp_length=10.0, support_length=60.0)
    )
    base = base.with_loads(*base.loads, fr.PointLoad(1, 40.0, (0.5, 0.0, 0.0)))
    changes = {
        "adaptor.support_length": 58.0,
        "adaptor.back_clamp_length": 11.0,
        "adaptor.front_clamp_length": 5.0,
        "crossbeams.angle[2]": 0.02,
        "crossbeams.angle": np.linspace(-0.02, 0.02, C),
        "crossbeams.front_s[3]": 48.0,
        "crossbeams.back_s[5]": 95.0,
        "crossbeams.thickness[1]": 2.2,
        "crossbeams.depth[0]": 18.0,
        "front.thickness": 3.2,
        "back.thickness": 2.8,
        "front.depth": 19.0,
        "back.depth": 21.0,
        "depth": 22.0,
        "material.E": 14.0,
        "material.nu": 0.4,
        "tip.x": 1.0,
        "tip.z": 119.0,
        "front.curvature": 0.001,
    }
    # back.curvature: a clamp on a curved back beam is not supported (FingerError).
    assert set(design.DESIGN_VALUES) - {"back.curvature"} <= {n.split("[")[0] for n in changes}
    topo = fr.topology_of(base, "planar")
    variants = {}
    for name, value in changes.items():
        f = design.set_design(base, {name: value})
        fr.validate_finger(f)
        # Valid for the base topology (order of events kept). With contact (here the
        # support) topology_of(f) itself may differ: the number of sub-cuts between two
        # events is fixed from the concrete lengths (_cuts._subdivide), so an eager
        # solve_finger without topology= would recompile; with topology= it does not.
        assert bool(design.design_valid(f, topo)), name
        variants[name] = f

    traces = []

    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def solve(finger):
        traces.append(1)
        sol = fr.solve_finger(finger, topology=topo)
        return sol.result, sol.tip.position, sol.back.position

    ref = solve(base)
    compiles, got = [], {}
    listener = lambda event, duration, **kw: compiles.append(event)
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        for name, f in variants.items():
            got[name] = solve(f)
        jax.block_until_ready(got)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert len(traces) == 1
    assert not [e for e in compiles if "compile" in e], compiles
    assert int(ref[0]._value) == int(fr.RESULTS.successful._value)
    for name, (result, tip, back) in got.items():
        assert int(result._value) == int(fr.RESULTS.successful._value), name
        moved = max(
            np.max(np.abs(np.asarray(tip) - np.asarray(ref[1]))),
            np.max(np.abs(np.asarray(back) - np.asarray(ref[2]))),
        )
        assert moved > 1e-6, f"{name} did not change the answer"


@pytest.mark.parametrize("mode", ["planar", "spatial"])
def test_rigid_column_shares_the_length_direction(mode):
    """flow_jacobians derives d/d rigid from the length column's integrated direction and
    the state Jacobian (the rigid transport's start tangent) instead of integrating it:
    the same Jacobians at every step point as integrating both, on a back beam clamped
    over 7 mm with a distributed load inside the clamp (so the transport moves the
    position, the force and the moment)."""
    from finray_jax import _flow, _solve
    from finray_jax._finger import DistributedLoad

    f = design.set_design(fr.ref_finger_a("L3"), {"adaptor.back_clamp_length": 7.0})
    f = f.with_loads(*f.loads, DistributedLoad(1, (0.0, 20.0), (0.3, 0.0, 0.2)))
    inside = r"loads\[1\] .* lies partly inside the back beam's clamped length 7.0 mm"
    with pytest.warns(fr.FingerWarning, match=inside):
        topo = fr.topology_of(f, mode)
    integ = fr.Integrator()
    with pytest.warns(fr.FingerWarning, match=inside):
        y = fr.solve_finger(f, topology=topo).unknowns
    p = _solve.nograd(_solve.make_problem(topo, integ, f))
    Y0 = p.start_states(y.reshape(p.table.length.shape[0], -1))
    Q = p.params(1.0)
    assert int(jnp.sum(p.table.rigid > 0)) >= 1
    cols = np.array([0, 1, 5])
    run = lambda merge: _flow.flow_jacobians(
        p.model, integ, Y0, Q, save_all=True, q_columns=cols, merge_rigid=merge
    )
    out, jy, jq = jax.jit(lambda: run(True))()
    out0, jy0, jq0 = jax.jit(lambda: run(False))()
    np.testing.assert_array_equal(np.asarray(out), np.asarray(out0))
    np.testing.assert_allclose(np.asarray(jy), np.asarray(jy0), rtol=0, atol=1e-13)
    scale = float(jnp.max(jnp.abs(jq0[..., 1])))
    assert scale > 1.0
    np.testing.assert_allclose(np.asarray(jq), np.asarray(jq0), rtol=0, atol=1e-12 * scale)
