"""Named design values and outputs (finray_jax.design), and gradients of outputs through
`solve_finger` against central finite differences.

The gradient tests compile the fully traced solve under `jax.jacfwd` and `jax.grad` in one
module fixture: 1.5-3 minutes on the 2-core test machine, depending on its load.
"""

import dataclasses
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import round_trip_finger

import finray_jax as fr
from finray_jax import design
from finray_jax import io as fio

EXAMPLES = pathlib.Path(__file__).resolve().parent.parent / "examples"

# ref-A under L1 with both bases clamped over 8 mm (short of the first crossbeam at 15 mm),
# so that the clamp lengths are interior values and their derivatives are two-sided.
BASE = design.set_design(
    fr.ref_finger_a("L1"), {"adaptor.front_clamp_length": 8.0, "adaptor.back_clamp_length": 8.0}
)
# "depth" sets every depth; the later "front.depth" then overrides the front one, so both
# derivatives are non-zero. crossbeams.front_s[3] is not used: it ties with the load point.
NAMES = [
    "adaptor.back_clamp_length",
    "adaptor.front_clamp_length",
    "crossbeams.front_s[2]",
    "crossbeams.back_s[4]",
    "crossbeams.thickness[1]",
    "crossbeams.angle[3]",
    "front.thickness",
    "back.thickness",
    "depth",
    "front.depth",
    "material.E",
    "tip.x",
    "tip.z",
]
OUTS = ["tip.dx", "reaction.front.fx", "max_strain"]


# --------------------------------------------------------------------------------------
# Names, get and set
# --------------------------------------------------------------------------------------


def test_get_set_round_trip():
    f = fr.ref_finger_a("L1")
    g = design.set_design(f, {"crossbeams.thickness[2]": 1.25, "back.thickness": 2.0})
    got = design.get_design(
        g, ["crossbeams.thickness", "crossbeams.thickness[2]", "back.thickness"]
    )
    np.testing.assert_array_equal(got["crossbeams.thickness"], [1, 1, 1.25, 1, 1, 1, 1])
    assert float(got["crossbeams.thickness[2]"]) == 1.25
    assert float(got["back.thickness"]) == 2.0
    assert float(f.back.thickness) == 1.5  # the original is unchanged
    g = design.set_design(f, {"depth": 10.0})
    assert float(g.front.depth) == float(g.back.depth) == 10.0
    np.testing.assert_array_equal(g.crossbeams.depth, np.full(7, 10.0))


def test_crossbeam_angle_moves_the_back_attachment():
    f = fr.ref_finger_a("L1")
    # ref-A's crossbeams are horizontal.
    np.testing.assert_allclose(
        design.get_design(f, ["crossbeams.angle"])["crossbeams.angle"], 0, atol=1e-14
    )
    g = design.set_design(f, {"crossbeams.angle[2]": 0.1})
    np.testing.assert_array_equal(g.crossbeams.front_s, f.crossbeams.front_s)
    changed = np.flatnonzero(np.asarray(g.crossbeams.back_s) != np.asarray(f.crossbeams.back_s))
    assert changed.tolist() == [2]
    # The back end lies on the back beam (x = 40 (1 - z / 120)) at 0.1 rad above the front end
    # (0, 45): z = 45 + x tan(0.1).
    s = float(g.crossbeams.back_s[2])
    x, z = 40.0 * (1 - s / np.hypot(40, 120) * 1.0), 120.0 * s / np.hypot(40, 120)
    assert z == pytest.approx(45.0 + x * np.tan(0.1), rel=1e-13)
    assert float(
        design.get_design(g, ["crossbeams.angle[2]"])["crossbeams.angle[2]"]
    ) == pytest.approx(0.1, abs=1e-14)
    fr.validate_finger(g)


def test_crossbeam_angle_on_a_curved_back_beam():
    f = fr.Finger(
        material=BASE.material,
        front_base=BASE.front_base,
        back_base=BASE.back_base,
        tip=BASE.tip,
        front=BASE.front,
        back=BASE.back,
        crossbeams=BASE.crossbeams,
        loads=BASE.loads,
        back_curvature=0.004,
    )
    want = np.linspace(-0.1, 0.1, 7)
    g = design.set_design(f, {"crossbeams.angle": want})
    np.testing.assert_allclose(
        design.get_design(g, ["crossbeams.angle"])["crossbeams.angle"], want, atol=1e-13
    )


def test_angles_are_applied_after_front_s():
    f = fr.ref_finger_a("L1")
    g = design.set_design(f, {"crossbeams.angle[2]": 0.05, "crossbeams.front_s[2]": 40.0})
    assert float(g.crossbeams.front_s[2]) == 40.0
    assert float(design.crossbeam_angle(g)[2]) == pytest.approx(0.05, abs=1e-14)


@pytest.mark.parametrize(
    "name, match",
    [
        (
            "crossbeams.foo",
            r"unknown design value 'crossbeams.foo'; valid names: material.E, "
            r".*crossbeams.angle\[0..6\]",
        ),
        (
            "crossbeams.thickness[7]",
            r"no crossbeam 7; this finger has 7 crossbeams \(indices 0..6\)",
        ),
        ("tip.x[1]", r"'tip.x' takes no index"),
        ("front thickness", r"unknown design value 'front thickness'"),
        (
            "crossbeam.thickness[2]",
            r"'crossbeam.thickness\[2\]' \(did you mean 'crossbeams.thickness\[2\]'\?\)",
        ),
        ("adaptor.back_clamp_lenght", r"\(did you mean 'adaptor.back_clamp_length'\?\)"),
    ],
)
def test_unknown_names(name, match):
    with pytest.raises(design.DesignError, match=match):
        design.set_design(fr.ref_finger_a("L1"), {name: 1.0})


def test_names_listed_where_scalars_are_needed_are_scalars():
    """Where one number is needed (sweeps, optimisation), the list of valid names offers a
    per-crossbeam value only with its index; set_design takes whole arrays too."""
    f = fr.ref_finger_a("L1")
    with pytest.raises(design.DesignError) as scalar:
        design.check_design_names(f, ["nope"], scalar=True)
    with pytest.raises(design.DesignError) as whole:
        design.check_design_names(f, ["nope"])
    assert "crossbeams.thickness[0..6]" in str(scalar.value)
    assert "crossbeams.thickness," not in str(scalar.value)
    assert "crossbeams.thickness, crossbeams.thickness[0..6]" in str(whole.value)


def test_whole_array_names_are_refused_where_scalars_are_needed():
    with pytest.raises(
        design.DesignError, match=r"crossbeams.front_s.*array of 7 numbers.*crossbeams.front_s\[0\]"
    ):
        design.check_design_names(fr.ref_finger_a("L1"), ["crossbeams.front_s"], scalar=True)


def test_design_valid():
    f = fr.ref_finger_a("L1")
    topo = fr.topology_of(f, "planar")
    ok = lambda values: bool(design.design_valid(design.set_design(f, values), topo))
    assert ok({})
    assert ok({"adaptor.back_clamp_length": 10.0})
    assert not ok({"front.thickness": np.nan})
    assert not ok({"crossbeams.thickness[0]": 0.0})
    assert not ok({"crossbeams.front_s[2]": 65.0})  # past the load point at 60: new topology
    assert not ok({"crossbeams.back_s[6]": 130.0})  # beyond the back beam
    assert not ok({"adaptor.front_clamp_length": -1.0})
    assert not ok({"material.nu": 0.5})


# --------------------------------------------------------------------------------------
# design_valid holds validate_finger's geometry rules: main beams apart except at the tip,
# never crossing; crossbeams long enough (docs/finger-format.md, "Geometry rules")
# --------------------------------------------------------------------------------------

REF = fr.ref_finger_a("L1")
NO_CROSSBEAMS = fr.Crossbeams(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
BARE = dataclasses.replace(REF, crossbeams=NO_CROSSBEAMS)  # ref-A's main beams alone
# design_valid jitted, the topology static (one compilation per finger structure)
VALID = jax.jit(design.design_valid, static_argnums=1)


def _topology(finger):
    return fr.topology_of(finger, "planar")


def _refusal(finger) -> str | None:
    """validate_finger's message, or None when it accepts the finger."""
    try:
        fr.validate_finger(finger)
    except fr.FingerError as e:
        return str(e)
    return None


def _with(finger, **kw):
    """A copy of finger with other fields (points as (x, z) tuples)."""
    kw = {k: np.asarray(v) if isinstance(v, tuple) else v for k, v in kw.items()}
    return dataclasses.replace(finger, **kw)


# (finger, the valid finger whose topology a batch of it would use, validate_finger's words)
REFUSED = {
    "back base on the front beam": (
        _with(BARE, back_base=(0.0, 10.0)),
        BARE,
        "back_base = [0.0, 10.0] lies on the front beam's centreline",
    ),
    "back base 1 mm from the front beam": (
        _with(BARE, back_base=(1.0, 0.0)),
        BARE,
        "lies 1 mm from the front beam's centreline",
    ),
    "back base 0.5 mm beside the front beam": (
        _with(BARE, back_base=(-0.5, 30.0)),
        BARE,
        "lies 0.5 mm from the front beam's centreline",
    ),
    "front base on the back beam": (
        _with(BARE, back_base=(0.0, -10.0)),
        BARE,
        "front_base = [0.0, 0.0] lies on the back beam's centreline",
    ),
    "back beam bowing across the front beam": (
        _with(REF, back_curvature=0.01),
        REF,
        "the back beam crosses the front beam",
    ),
    "back beam crossing near the base": (
        _with(REF, back_curvature=0.015),
        REF,
        "the back beam crosses the front beam at (x, z) = (0, 13.34)",
    ),
    "front beam bowing across the back beam": (
        _with(REF, front_curvature=-0.006),
        REF,
        "the back beam crosses the front beam",
    ),
    "beams 2 mm apart at the base": (
        _with(BARE, back_base=(2.0, 0.0)),
        BARE,
        "centrelines come within",
    ),
    "beams 5 mm apart at the base": (
        _with(BARE, back_base=(5.0, 0.0)),
        BARE,
        "centrelines come within",
    ),
    "front beam thickening toward the tip": (  # accepted with a constant 1.5 mm
        _with(BARE, back_base=(7.0, 0.0), front=fr.Section(1.5, 20.0, tip_thickness=3.0)),
        _with(BARE, front=fr.Section(1.5, 20.0, tip_thickness=3.0)),
        "centrelines come within 1.747 mm",
    ),
    "short crossbeam near the tip": (
        design.set_design(REF, {"crossbeams.front_s[6]": 119.5, "crossbeams.angle[6]": 0.0}),
        REF,
        "crossbeams[6] is 0.1667 mm long",
    ),
}


CURVED_BACK = _with(REF, back_curvature=0.003)
PINNED_FRONT = _with(REF, adaptor=fr.Adaptor(front_base=fr.PinnedBase()))
SUPPORTED = _with(
    REF, adaptor=fr.Adaptor(front_base=fr.PinnedBase(), back_clamp_length=20.0, support_length=60.0)
)


def _adaptor(finger, **kw):
    return _with(finger, adaptor=dataclasses.replace(finger.adaptor, **kw))


# (finger, the valid finger whose topology a batch of it would use, validate_finger's words)
ADAPTOR_REFUSED = {
    "clamp on a curved back beam": (
        _adaptor(CURVED_BACK, back_clamp_length=10.0),
        CURVED_BACK,
        "a clamp on a curved beam is not supported yet",
    ),
    "clamp length on a pinned front base": (
        _adaptor(PINNED_FRONT, front_clamp_length=5.0),
        PINNED_FRONT,
        "needs adaptor.front_base = 'clamped'",
    ),
    "support shorter than the clamp": (
        _adaptor(SUPPORTED, support_length=15.0),
        SUPPORTED,
        "adaptor.support_length = 15.0 must lie in [back_clamp_length, back beam length]",
    ),
    "support beyond the back beam": (
        _adaptor(SUPPORTED, support_length=127.0),
        SUPPORTED,
        "adaptor.support_length = 127.0 must lie in [back_clamp_length, back beam length]",
    ),
    "support behind a curved back beam": (
        _with(_adaptor(SUPPORTED, back_clamp_length=0.0), back_curvature=0.003),
        _adaptor(SUPPORTED, back_clamp_length=0.0),
        "adaptor.support_length needs a straight back beam",
    ),
}


@pytest.mark.parametrize("name", list(REFUSED) + list(ADAPTOR_REFUSED))
def test_design_valid_refuses_what_validate_finger_refuses(name):
    """Each finger breaks one geometry rule (REFUSED) or adaptor rule (ADAPTOR_REFUSED) and
    nothing else; design_valid refuses it too, or a batch, sweep or optimiser step of it
    would be solved as if valid."""
    finger, base, words = {**REFUSED, **ADAPTOR_REFUSED}[name]
    msg = _refusal(finger)
    assert msg is not None and words in msg, msg
    assert _refusal(base) is None
    assert bool(VALID(base, _topology(base)))
    assert not bool(VALID(finger, _topology(base)))


def _example(name):
    return fio.load_finger(EXAMPLES / name)[0]


ACCEPTED = {
    "ref-A": REF,
    "examples/finger1.toml": _example("finger1.toml"),
    "examples/finger2.toml": _example("finger2.toml"),
    "examples/grasp_finger1_modified.toml": _example("grasp_finger1_modified.toml"),
    "mirrored": _with(BARE, back_base=(-40.0, 0.0)),
    "back base below the front base": _with(BARE, back_base=(40.0, -20.0)),
    "narrow, overlapping only near the tip": _with(BARE, back_base=(6.5, 0.0)),
    "both beams curved": _with(BARE, front_curvature=0.004, back_curvature=-0.003),
    "nearly tangent at the tip": _with(REF, back_curvature=0.005),
    "tapered front beam": _with(BARE, front=fr.Section(1.5, 20.0, tip_thickness=3.0)),
    "narrow, front beam thinning toward the tip": _with(
        BARE, back_base=(7.0, 0.0), front=fr.Section(1.5, 20.0, tip_thickness=0.5)
    ),
    "test_toml's round-trip finger (tapered, curved)": round_trip_finger(),
}


@pytest.mark.parametrize("name", list(ACCEPTED))
def test_design_valid_accepts_what_validate_finger_accepts(name):
    finger = ACCEPTED[name]
    assert _refusal(finger) is None
    assert bool(VALID(finger, _topology(finger)))


def _back_base_x(finger):
    return lambda x: eqx.tree_at(lambda f: f.back_base, finger, jnp.stack([x, 0.0]))


def _set(finger, name, **also):
    return lambda x: design.set_design(finger, {name: x, **also})


def _tip_thickness(finger):
    return lambda t: eqx.tree_at(lambda f: f.front.tip_thickness, finger, t)


TAPERED_NARROW = _with(BARE, back_base=(7.0, 0.0), front=fr.Section(1.5, 20.0, tip_thickness=1.5))

# name -> (how a value makes a design, the values, the base finger (whose topology is used))
SWEEPS = {
    "back base x": (_back_base_x(BARE), [2.0, 5.0, 6.5, 40.0], BARE),
    "back.curvature": (_set(REF, "back.curvature"), [0.0, 0.004, 0.0052, 0.01], REF),
    "front.curvature": (_set(REF, "front.curvature"), [-0.006, -0.003, 0.0, 0.004], REF),
    "tip.x, curved back beam": (
        _set(_with(REF, back_curvature=0.005), "tip.x"),
        [-10.0, -2.0, 0.0, 5.0],
        _with(REF, back_curvature=0.005),
    ),
    "front.thickness, narrow": (
        _set(_with(BARE, back_base=(8.0, 0.0)), "front.thickness"),
        [1.5, 2.0, 3.0],
        _with(BARE, back_base=(8.0, 0.0)),
    ),
    "front tip thickness, narrow": (
        _tip_thickness(TAPERED_NARROW),
        [0.5, 1.5, 3.0],
        TAPERED_NARROW,
    ),
    "crossbeams.front_s[6], horizontal": (
        _set(REF, "crossbeams.front_s[6]", **{"crossbeams.angle[6]": 0.0}),
        [105.0, 117.0, 118.0, 119.5],
        REF,
    ),
}


@pytest.mark.parametrize("name", list(SWEEPS))
def test_design_valid_vmapped_agrees_with_validate_finger(name):
    """A vmapped batch moving one design value across a geometry rule's limit: valid and
    invalid members, each as validate_finger decides."""
    make, values, base = SWEEPS[name]
    topo = _topology(base)
    got = jax.jit(jax.vmap(lambda x: design.design_valid(make(x), topo)))(jnp.asarray(values))
    want = [_refusal(jax.device_get(make(jnp.asarray(x)))) is None for x in values]
    assert True in want and False in want  # the batch mixes valid and invalid designs
    assert np.asarray(got).tolist() == want


def test_design_valid_under_grad():
    """design_valid is a bool that gates differentiable values (as in a batch, where an
    invalid design is swapped for the base finger): gradients through the gate stay finite,
    for a straight finger (design_valid's straight-beam branch) and vmapped over
    curvatures (both branches at once), zero for the invalid member."""
    topo = _topology(REF)

    def gated(x, name):
        finger = design.set_design(REF, {name: x})
        ok = design.design_valid(finger, topo)
        return jnp.where(ok, jnp.sum(design.crossbeam_angle(finger)), 0.0)

    g = jax.jit(jax.grad(gated), static_argnums=1)(0.0, "tip.x")
    assert np.isfinite(float(g)) and float(g) != 0.0
    kappas = jnp.array([0.0, 0.004, 0.01])  # the last crosses the front beam
    grads = jax.jit(jax.vmap(jax.grad(gated), in_axes=(0, None)), static_argnums=1)(
        kappas, "back.curvature"
    )
    assert np.all(np.isfinite(grads)) and float(grads[2]) == 0.0 and float(grads[1]) != 0.0


# --------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def l1_solution():
    return fr.solve_finger(BASE, mode="planar")


def test_outputs(l1_solution):
    sol = l1_solution
    out = design.evaluate_outputs(
        sol, BASE, ["tip.dx", "tip.dz", "tip.rotation", "reaction.back.my"]
    )
    assert float(out["tip.dx"]) == float(sol.tip.displacement[0])
    assert float(out["tip.dz"]) == float(sol.tip.displacement[2])
    assert float(out["tip.rotation"]) == float(sol.tip.rotation[1])
    assert float(out["reaction.back.my"]) == float(sol.reactions_back.moment[1])
    with pytest.raises(design.DesignError, match=r"unknown output 'tip.dq'; valid outputs: tip.dx"):
        design.evaluate_outputs(sol, BASE, ["tip.dq"])


def test_max_strain_by_hand(l1_solution):
    """|n . d3| / (E t d) + |m . d2| (t / 2) / (E d t^3 / 12) over both main beams, outside
    the 8 mm clamps."""
    sol, E, t, d = l1_solution, 12.0, 1.5, 20.0
    worst = 0.0
    for beam in (sol.front, sol.back):
        s = np.asarray(beam.s)
        R = np.asarray(beam.frame)
        n3 = np.einsum("ni,ni->n", np.asarray(beam.force), R[:, :, 2])
        m2 = np.einsum("ni,ni->n", np.asarray(beam.moment), R[:, :, 1])
        eps = np.abs(n3) / (E * t * d) + np.abs(m2) * (t / 2) / (E * d * t**3 / 12)
        worst = max(worst, float(np.max(eps[s >= 8.0 - 1e-9])))
    got = design.evaluate_outputs(sol, BASE, ["max_strain"])["max_strain"]
    assert float(got) == pytest.approx(worst, rel=1e-14)
    assert 1e-4 < worst < 1e-2  # a soft finger under 0.05 N


def test_register_output(l1_solution):
    design.register_output("test.tip_dx_um", lambda sol, f: 1e3 * sol.tip.displacement[0])
    try:
        out = design.evaluate_outputs(l1_solution, BASE, ["test.tip_dx_um"])
        assert float(out["test.tip_dx_um"]) == pytest.approx(
            1e3 * float(l1_solution.tip.displacement[0])
        )
        with pytest.raises(design.DesignError, match="exists already"):
            design.register_output("test.tip_dx_um", lambda sol, f: 0.0)
    finally:
        design.OUTPUTS.pop("test.tip_dx_um")


# --------------------------------------------------------------------------------------
# Gradients against central finite differences
# --------------------------------------------------------------------------------------


def _outputs(x, topo):
    finger = design.set_design(BASE, dict(zip(NAMES, x)))
    sol = fr.solve_finger(finger, mode="planar", topology=topo)
    out = design.evaluate_outputs(sol, finger, OUTS)
    return jnp.stack([out[k] for k in OUTS])


@pytest.fixture(scope="module")
def derivatives():
    topo = fr.topology_of(BASE, "planar")
    x0 = jnp.stack([jnp.asarray(v) for v in design.get_design(BASE, NAMES).values()])
    jac = np.asarray(jax.jit(jax.jacfwd(lambda x: _outputs(x, topo)))(x0))
    grad = jax.jit(jax.grad(lambda x, w: jnp.dot(w, _outputs(x, topo))))
    rows = np.stack([np.asarray(grad(x0, jnp.eye(len(OUTS))[k])) for k in range(len(OUTS))])

    # Central differences of eager solves. Step 1e-4 relative (1e-4 absolute for values
    # near 0): truncation ~ h^2 f''' / 6 is ~1e-8 relative; the solves converge to a
    # residual of ~1e-15, so their noise divided by h is ~1e-11.
    def eager(x):
        finger = design.set_design(BASE, dict(zip(NAMES, x)))
        sol = fr.solve_finger(finger, mode="planar", topology=topo)
        assert sol.status == "converged"
        out = design.evaluate_outputs(sol, finger, OUTS)
        return np.array([float(out[k]) for k in OUTS])

    x0n = np.asarray(x0)
    fd = np.zeros_like(jac)
    for i in range(len(NAMES)):
        h = 1e-4 * max(abs(x0n[i]), 1.0)
        e = np.zeros_like(x0n)
        e[i] = h
        fd[:, i] = (eager(x0n + e) - eager(x0n - e)) / (2 * h)
    return jac, rows, fd


def _rel(a, b):
    return np.abs(a - b) / np.abs(b)


@pytest.mark.parametrize("k", range(len(OUTS)), ids=OUTS)
def test_jacfwd_matches_finite_differences(derivatives, k):
    jac, _, fd = derivatives
    assert np.all(fd[k] != 0.0)
    err = _rel(jac[k], fd[k])
    assert np.all(err < 1e-5), dict(zip(NAMES, err))


@pytest.mark.parametrize("k", range(len(OUTS)), ids=OUTS)
def test_grad_matches_finite_differences(derivatives, k):
    _, rows, fd = derivatives
    err = _rel(rows[k], fd[k])
    assert np.all(err < 1e-5), dict(zip(NAMES, err))
