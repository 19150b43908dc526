"""The banded Newton solve: its pattern covers the real Jacobian, it gives the dense LU's
step and determinant sign, and the segment flow's reduced-direction JVP is exact."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import finray_jax as fr
import finray_jax.io
from finray_jax import _banded, _flow, _integrator, _solve, _spatial_rod
from finray_jax._rotation import exp_so3

MODIFIED = fr.Adaptor(front_base=fr.PinnedBase(), back_clamp_length=20.0, support_length=60.0)


@pytest.fixture(scope="module")
def grasped():
    finger, _ = fr.io.load_finger("examples/finger1.toml")
    finger = eqx.tree_at(lambda f: f.objects, finger.with_loads(), (fr.Circle((-11.0, 60.0), 9.0),))
    finger = eqx.tree_at(lambda f: f.adaptor, finger, MODIFIED)
    return fr.grasp(finger, 3.0)


def _cases():
    ref = fr.ref_finger_a("L1")
    pinned = eqx.tree_at(
        lambda f: f.adaptor, ref, fr.Adaptor(front_base=fr.PinnedBase(), back_clamp_length=20.0)
    )
    out_of_plane = ref.with_loads(fr.PointLoad(beam=0, s=60.0, force=(0.05, 0.02, 0.0)))
    return {
        "refA-L1-planar": (ref, fr.topology_of(ref, "planar")),
        "refA-L1-spatial": (ref, fr.topology_of(ref, "spatial")),
        "refA-L3-planar": (fr.ref_finger_a("L3"), fr.topology_of(fr.ref_finger_a("L3"), "planar")),
        "pinned-clamp-planar": (pinned, fr.topology_of(pinned, "planar")),
        "out-of-plane-spatial": (out_of_plane, fr.topology_of(out_of_plane, "spatial")),
    }


# One case in the default suite (each compiles a Jacobian, a banded and a dense solve);
# the contact case runs in test_contact on its grasps.
CASES = ["refA-L1-planar"] + [
    pytest.param(name, marks=pytest.mark.slow)
    for name in (
        "refA-L1-spatial",
        "refA-L3-planar",
        "pinned-clamp-planar",
        "out-of-plane-spatial",
        "grasp-support-planar",
    )
]


@pytest.mark.parametrize("name", CASES)
def test_banded_step_equals_the_dense_step(request, name):
    if name == "grasp-support-planar":
        g = request.getfixturevalue("grasped")
        check_banded_step(g.finger, g.topology, g.solution.unknowns)
    else:
        check_banded_step(*_cases()[name])


def check_banded_step(finger, topo, at=None):
    """The banded Newton step against dense linear algebra at a random state near the
    undeformed one (away from any symmetry), or at a grasp's equilibrium `at`: there the
    stiff support's penalty makes a random state meaningless (with the whole supported
    length pressed in, the shooting grows exponentially along it: cond J ~ 1e35 at a
    1e-3 perturbation, where the sign of det J is round-off; ~1e12 at the equilibrium)."""
    problem = _solve.make_problem(topo, fr.Integrator(), finger)
    if at is None:
        rng = np.random.default_rng(0)
        y = problem.undeformed().reshape(-1)
        y = y + 1e-2 * jnp.asarray(rng.standard_normal(y.shape))
    else:
        y = jnp.asarray(at).reshape(-1)
    lam = jnp.asarray(0.7)
    plan = topo.band

    @eqx.filter_jit
    def everything(problem, y):
        fn = lambda y: _solve.natural_residual(y, (problem, lam))
        r, A = _banded.linearize(plan, fn, y)
        dy, r2, sign = _solve.newton_step(problem, lam, y, fr.BandedLinearSolver())
        Jc = _banded.dense(plan, _banded.compressed(plan, fn, y)[1])
        return jax.jacfwd(fn)(y), r, A, dy, r2, sign, Jc

    J, r, A, dy, r2, sign, Jc = (np.asarray(x) for x in everything(problem, y))
    # The static pattern (from the topology alone) holds every non-zero of the Jacobian.
    assert _banded.covers(plan, J)
    assert plan.kl + plan.ku + 1 < plan.n  # and it is a real band, not the whole matrix
    # The band assembled from one tangent per colour is the Jacobian itself.
    np.testing.assert_allclose(A, np.asarray(_banded.pad(plan, J)), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Jc, J, rtol=1e-12, atol=1e-12)
    # Newton's step solves J dy = r as well as a dense LU does (backward error at round-off;
    # the contact Jacobian is too ill-conditioned to compare the steps themselves closely),
    # and the sign of det J (which marks folds) is the same.
    np.testing.assert_array_equal(r2, r)
    backward = np.max(np.abs(J @ dy - r)) / (np.max(np.abs(J)) * np.max(np.abs(dy)))
    assert backward < 1e-13
    dense = np.linalg.solve(J, r)
    forward = np.max(np.abs(dy - dense)) / np.max(np.abs(dense))
    assert forward < 1e-14 * np.linalg.cond(J)
    assert float(sign) == np.linalg.slogdet(J)[0]


def test_banded_lu_on_a_hidden_band_matrix():
    """A random block-tridiagonal matrix with its blocks renumbered at random: the plan
    finds the band again, and solve and sign match numpy."""
    rng = np.random.default_rng(1)
    nb, blocks = 3, 20
    hidden = rng.permutation(blocks)
    row_blocks = []
    for k in range(blocks):  # block row k reads hidden blocks k-1, k, k+1
        row_blocks += [{int(hidden[j]) for j in (k - 1, k, k + 1) if 0 <= j < blocks}] * nb
    n = nb * blocks
    J = np.zeros((n, n))
    for i, deps in enumerate(row_blocks):
        for b in deps:
            J[i, b * nb : (b + 1) * nb] = rng.standard_normal(nb)
    plan = _banded.plan_band(row_blocks, nb, blocks)
    assert _banded.covers(plan, J)
    assert plan.kl + plan.ku <= 6 * nb  # a band of a few blocks, not n = 60
    b = rng.standard_normal(n)
    fac = _banded.factor(plan, _banded.pad(plan, jnp.asarray(J)))
    x = _banded.solve_factored(plan, fac, jnp.asarray(b))
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(J, b), rtol=1e-9, atol=1e-9)
    assert float(fac.sign) == np.linalg.slogdet(J)[0]


def _panels():
    """Panels (h, w) of the banded LU's steps: random, with ties and a zero column, and
    one where every pivot search must swap (the largest entry is always the last row).
    All 12 x 20 (one compiled program each way); a larger one, 35 x 58 with 17 pivots,
    compiles for 25 s more (slow)."""
    rng = np.random.default_rng(4)
    random = rng.standard_normal((12, 20))
    ties = np.round(rng.standard_normal((12, 20)))  # equal magnitudes: the first one wins
    ties[:, 2] = 0.0  # a zero column: no pivot, left as it is
    swaps = rng.uniform(0.1, 0.2, (12, 20))
    swaps[np.arange(12), np.arange(12)] = 0.01
    swaps[-1, :6] = 5.0
    large = rng.standard_normal((35, 58))
    return {"random": random, "ties-zero-column": ties, "swaps": swaps, "random-35x58": large}


@pytest.mark.parametrize(
    "name",
    ["random", "ties-zero-column", "swaps", pytest.param("random-35x58", marks=pytest.mark.slow)],
)
def test_elementwise_panel_matches_lapack(name):
    """The GPU's element-wise LU step (`_panel_elementwise`, chosen off the CPU) gives
    LAPACK's factors, row order and determinant sign (`_panel_lapack`, the CPU's), also
    vmapped, and the reconstruction P W = L [U; Schur] holds."""
    W = jnp.asarray(_panels()[name])
    nb = min(18, W.shape[0] // 2)
    ref = jax.jit(_banded._panel_lapack, static_argnums=1)(W, nb)
    got = jax.jit(_banded._panel_elementwise, static_argnums=1)(W, nb)
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(ref[1]))
    np.testing.assert_allclose(np.asarray(got[0]), np.asarray(ref[0]), rtol=1e-12, atol=1e-12)
    assert float(got[2]) == float(ref[2])
    out = np.asarray(got[0])
    L = np.eye(W.shape[0])
    L[:, :nb] += np.tril(out[:, :nb], -1)
    R = np.zeros_like(out)
    R[:nb] = np.triu(out[:nb])
    R[nb:, nb:] = out[nb:, nb:]
    np.testing.assert_allclose(L @ R, np.asarray(W)[np.asarray(got[1])], atol=1e-12)
    many = jax.vmap(lambda w: _banded._panel_elementwise(w, nb))(jnp.stack([W, -W]))
    np.testing.assert_allclose(np.asarray(many[0][0]), out, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(np.asarray(many[1][1]), np.asarray(ref[1]))
    assert float(many[2][1]) == float(ref[2]) * (-1.0) ** nb


def test_factor_picks_lapack_on_cpu(monkeypatch):
    """On the CPU the factorisation calls LAPACK (the element-wise step is slower there):
    a factor traced with the element-wise step poisoned still gives the right
    answer on the CPU backend."""
    if jax.default_backend() != "cpu":
        pytest.skip(f"checks the CPU's choice; the default backend is {jax.default_backend()}")
    poisoned = lambda W, nb: (W * jnp.nan, jnp.zeros(W.shape[0], jnp.int32), jnp.nan * W[0, 0])
    monkeypatch.setattr(_banded, "_panel_elementwise", poisoned)
    plan = _banded.plan_band([{0, 1}] * 3 + [{0, 1}] * 3, 3, 2)
    J = np.random.default_rng(2).standard_normal((6, 6))
    fac = jax.jit(lambda A: _banded.factor(plan, A))(_banded.pad(plan, jnp.asarray(J)))
    x = _banded.solve_factored(plan, fac, jnp.ones(6))
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(J, np.ones(6)), rtol=1e-10)


@pytest.mark.parametrize("mode", ["planar", pytest.param("spatial", marks=pytest.mark.slow)])
def test_both_linear_solvers_give_the_same_equilibrium(mode):
    finger = fr.ref_finger_a("L1")
    a = fr.solve_finger(
        finger, mode=mode, options=fr.SolverOptions(linear_solver=fr.DenseLinearSolver())
    )
    b = fr.solve_finger(
        finger, mode=mode, options=fr.SolverOptions(linear_solver=fr.BandedLinearSolver())
    )
    assert a.converged and b.converged
    np.testing.assert_allclose(b.tip.displacement, a.tip.displacement, rtol=0, atol=1e-10)
    np.testing.assert_allclose(b.reactions_back.force, a.reactions_back.force, rtol=0, atol=1e-10)


def test_unknown_linear_solver_is_named():
    with pytest.raises(ValueError, match="linear_solver.*'lu'"):
        fr.SolverOptions(linear_solver="lu")


def _flow_jvps(model, Y0u, theta, Q, dYu, dQ):
    """JVP of the segment flow (custom rule) and of plain autodiff through the integrator,
    with start states built from unknowns (so frame tangents lie on SO(3))."""
    integ = fr.Integrator()
    full = lambda yu: jax.vmap(model.full_from_unknown)(yu, theta)
    custom = lambda yu, q: _flow.segment_flow(model, integ, full(yu), q)
    plain = lambda yu, q: jax.vmap(lambda y, qq: _integrator.integrate(model, integ, y, qq, False))(
        full(yu), q
    )
    both = jax.jit(lambda *a: (jax.jvp(custom, a[:2], a[2:])[1], jax.jvp(plain, a[:2], a[2:])[1]))
    return both(Y0u, Q, dYu, dQ)


@pytest.mark.slow  # (the default suite's gradient and closed-form tests run through it)
@pytest.mark.parametrize("mode", ["planar", "spatial"])
def test_reduced_direction_flow_jvp_is_exact(grasped, mode):
    rng = np.random.default_rng(2)
    for finger, topo in (
        (fr.ref_finger_a("L1"), fr.topology_of(fr.ref_finger_a("L1"), mode)),
        (grasped.finger, dataclasses.replace(grasped.topology, mode=mode)),
    ):
        problem = _solve.make_problem(topo, fr.Integrator(), finger)
        model = problem.model
        Y = problem.undeformed() * problem.scale()
        Y = Y + 1e-2 * jnp.asarray(rng.standard_normal(Y.shape)) * problem.scale()
        Q = problem.params(1.0)
        dY = jnp.asarray(rng.standard_normal(Y.shape))
        dQ = 1e-3 * jnp.asarray(rng.standard_normal(Q.shape))
        a, b = _flow_jvps(model, Y, problem.table.theta, Q, dY, dQ)
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-10)
        assert model.translation_free == (topo.contact is None)


def test_spatial_tangent_basis_spans_frame_tangents():
    rng = np.random.default_rng(3)
    model = _spatial_rod.SpatialRod()
    R = exp_so3(jnp.asarray(rng.standard_normal(3)))
    y = jnp.concatenate([jnp.ones(3), R.reshape(9), jnp.arange(6.0)])
    w = jnp.asarray(rng.standard_normal(3))
    dR = R @ jnp.asarray([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    dy = jnp.concatenate([jnp.zeros(3), dR.reshape(9), jnp.asarray(rng.standard_normal(6))])
    E, d = model.tangent_basis(y), model.tangent_coords(y, dy)
    assert E.shape == (18, 9) and d.shape == (9,)
    np.testing.assert_allclose(np.asarray(E @ d), np.asarray(dy), atol=1e-14)


def test_banded_lu_is_a_lineax_solver():
    """`BandedLU` through lineax: `lineax.linear_solve` of ref-A's Jacobian (as a Jacobian
    operator of the residual) solves J x = b and its transpose as a dense solve does
    (backward error at round-off: the banded LU pivots within the band, a dense LU over
    whole columns, so the two agree to cond(J) x eps, not digit for digit)."""
    import lineax as lx

    from finray_jax._linear import BandedLU
    from finray_jax._newton import natural_residual

    finger = fr.ref_finger_a("L1")
    topo = fr.topology_of(finger, "planar")
    problem = _solve.make_problem(topo, fr.Integrator(), finger)
    rng = np.random.default_rng(1)
    y = problem.undeformed().reshape(-1)
    y = y + 1e-2 * jnp.asarray(rng.standard_normal(y.shape))
    lam = jnp.asarray(0.7)
    op = lx.JacobianLinearOperator(natural_residual, y, (problem, lam))
    J = np.asarray(jax.jacfwd(natural_residual)(y, (problem, lam)))
    b = jnp.asarray(rng.standard_normal(y.shape))
    solver = BandedLU(topo.band)
    x = np.asarray(lx.linear_solve(op, b, solver).value)
    # J^-T b by reverse mode through the solve (lineax transposes it with the solver's
    # `transpose`: the operator itself must have the plan's pattern, J's, not J^T's).
    xt = np.asarray(jax.grad(lambda c: jnp.dot(b, lx.linear_solve(op, c, solver).value))(b))
    scale = np.abs(J).max() * np.abs(x).max()
    np.testing.assert_allclose(J @ x, b, rtol=0, atol=1e-12 * scale)
    scale_t = np.abs(J).max() * np.abs(xt).max()
    np.testing.assert_allclose(J.T @ xt, b, rtol=0, atol=1e-12 * scale_t)


def test_optimistix_adjoint_with_banded_lu_gives_the_same_gradient():
    """The root's tangent from optimistix's implicit JVP with `BandedLU` (what
    `root_find`'s ImplicitAdjoint computes) equals the project's one-pass rule
    (finray_jax._implicit) on ref-A L2 planar, for the front beam's thickness: the same
    theorem solved with the same factors, so to round-off (1e-9 of the tangent, the
    Newton tolerance's effect on the root at which both are evaluated)."""
    import optimistix as optx

    from finray_jax._implicit import _root_primal, _root_rewrite, attach_implicit_gradient
    from finray_jax._linear import BandedLU

    base = fr.ref_finger_a("L2")
    topo = fr.topology_of(base, "planar")
    y = fr.solve_finger(base, mode="planar").unknowns.reshape(-1)
    one = jnp.ones(())

    def root(t, how):
        finger = eqx.tree_at(lambda f: f.front.thickness, base, t)
        problem = _solve.make_problem(topo, fr.Integrator(), finger)
        if how == "project":
            return attach_implicit_gradient(problem, one, y, fr.BandedLinearSolver())[0]
        inputs = (problem, one, jax.lax.stop_gradient(y))
        solver = BandedLU(topo.band)
        return optx.internal.implicit_jvp(_root_primal, _root_rewrite, inputs, frozenset(), solver)[
            0
        ]

    t0 = base.front.thickness
    ours = jax.jvp(lambda t: root(t, "project"), (t0,), (jnp.ones(()),))[1]
    theirs = jax.jvp(lambda t: root(t, "optimistix"), (t0,), (jnp.ones(()),))[1]
    np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-9 * np.abs(ours).max())
