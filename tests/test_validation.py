"""Eager validation: every rule of validate_finger (and of the option objects) raises a
ValueError that names the field and the offending value, before anything is compiled."""

import dataclasses
import pathlib
import re
import warnings

import equinox as eqx
import numpy as np
import pytest
from helpers import round_trip_finger

import finray_jax as fr

EXAMPLES = pathlib.Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture(scope="module")
def finger():
    return fr.ref_finger_a("L1")


def _raises(finger, *fragments, func=fr.validate_finger):
    """validate_finger(finger) raises a FingerError whose message holds every fragment."""
    with pytest.raises(fr.FingerError) as info:
        func(finger)
    msg = str(info.value)
    for frag in fragments:
        if isinstance(frag, re.Pattern):
            assert frag.search(msg), f"{frag.pattern!r} not in {msg!r}"
        else:
            assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


def _cb_field(name, i):
    """The name of a crossbeam field, with or without the crossbeam's index."""
    return re.compile(rf"crossbeams(\[{i}\])?\.{name}\b")


def _material(finger, **kw):
    m = finger.material
    args = dict(E=m.E, nu=m.nu, shear_coefficient=m.shear_coefficient) | kw
    return eqx.tree_at(lambda f: f.material, finger, fr.Material(**args))


def _crossbeams(finger, **kw):
    cb = finger.crossbeams
    args = dict(front_s=cb.front_s, back_s=cb.back_s, thickness=cb.thickness, depth=cb.depth)
    return eqx.tree_at(lambda f: f.crossbeams, finger, fr.Crossbeams(**(args | kw)))


def _adaptor(finger, **kw):
    return eqx.tree_at(lambda f: f.adaptor, finger, fr.Adaptor(**kw))


def test_reference_finger_is_valid(finger):
    for load in ("none", "L1", "L2", "L3"):
        fr.validate_finger(fr.ref_finger_a(load))
    assert issubclass(fr.FingerError, ValueError)


def test_ref_finger_a_rejects_unknown_load_case():
    with pytest.raises(ValueError, match="L4"):
        fr.ref_finger_a("L4")


# --- material -----------------------------------------------------------------------


@pytest.mark.parametrize("E", [0.0, -12.0])
def test_non_positive_E(finger, E):
    _raises(_material(finger, E=E), "material.E", repr(E))


@pytest.mark.parametrize("nu", [0.5, 0.7, -1.0, -1.5])
def test_nu_out_of_range(finger, nu):
    _raises(_material(finger, nu=nu), "material.nu", repr(nu))


def test_nu_in_range_is_accepted(finger):
    for nu in (-0.99, 0.0, 0.499):
        fr.validate_finger(_material(finger, nu=nu))


@pytest.mark.parametrize("k", [0.0, -0.5])
def test_non_positive_shear_coefficient(finger, k):
    _raises(_material(finger, shear_coefficient=k), "material.shear_coefficient", repr(k))


# --- NaN / inf anywhere ---------------------------------------------------------------


NAN_CASES = {
    "material.E": lambda f: _material(f, E=np.nan),
    "material.nu": lambda f: _material(f, nu=np.nan),
    "material.shear_coefficient": lambda f: _material(f, shear_coefficient=np.inf),
    "front_base": lambda f: eqx.tree_at(lambda g: g.front_base, f, np.array([np.nan, 0.0])),
    "back_base": lambda f: eqx.tree_at(lambda g: g.back_base, f, np.array([40.0, np.nan])),
    "tip": lambda f: eqx.tree_at(lambda g: g.tip, f, np.array([np.inf, 120.0])),
    "front.thickness": lambda f: eqx.tree_at(lambda g: g.front, f, fr.Section(np.nan, 20.0)),
    "back.depth": lambda f: eqx.tree_at(lambda g: g.back, f, fr.Section(1.5, np.nan)),
    "crossbeams.front_s": lambda f: _crossbeams(
        f, front_s=np.where(np.arange(7) == 3, np.nan, np.asarray(f.crossbeams.front_s))
    ),
    "crossbeams.back_s": lambda f: _crossbeams(
        f, back_s=np.where(np.arange(7) == 0, np.nan, np.asarray(f.crossbeams.back_s))
    ),
    "crossbeams.thickness": lambda f: _crossbeams(f, thickness=np.full(7, np.nan)),
    "crossbeams.depth": lambda f: _crossbeams(f, depth=np.full(7, np.nan)),
    "adaptor.back_clamp_length": lambda f: _adaptor(f, back_clamp_length=np.nan),
    "loads[0].s": lambda f: f.with_loads(fr.PointLoad(0, np.nan, (0.05, 0.0, 0.0))),
    "loads[0].force": lambda f: f.with_loads(fr.PointLoad(0, 60.0, (np.nan, 0.0, 0.0))),
    "loads[0].moment": lambda f: f.with_loads(
        fr.PointLoad(0, 60.0, (0.05, 0.0, 0.0), (0.0, np.inf, 0.0))
    ),
    "loads[1].s_range": lambda f: f.with_loads(
        f.loads[0], fr.DistributedLoad(0, (np.nan, 80.0), (1.0, 0.0, 0.0))
    ),
    "loads[0].total_force": lambda f: f.with_loads(
        fr.DistributedLoad(0, (70.0, 80.0), (1.0, np.nan, 0.0))
    ),
}


NAN_CB_INDEX = {
    "crossbeams.front_s": 3,
    "crossbeams.back_s": 0,
    "crossbeams.thickness": 0,
    "crossbeams.depth": 0,
}


@pytest.mark.parametrize("field", list(NAN_CASES))
def test_non_finite_values(finger, field):
    name = field
    if field in NAN_CB_INDEX:
        name = _cb_field(field.split(".")[1], NAN_CB_INDEX[field])
    msg = _raises(NAN_CASES[field](finger), name, "finite")
    assert re.search(r"nan|inf", msg), msg


# --- geometry --------------------------------------------------------------------------


@pytest.mark.parametrize("beam", ["front", "back"])
@pytest.mark.parametrize("which", ["thickness", "depth"])
@pytest.mark.parametrize("value", [0.0, -1.5])
def test_non_positive_section(finger, beam, which, value):
    sec = dict(thickness=1.5, depth=20.0) | {which: value}
    bad = eqx.tree_at(lambda f: getattr(f, beam), finger, fr.Section(**sec))
    _raises(bad, f"{beam}.{which}", repr(value))


@pytest.mark.parametrize("which", ["thickness", "depth"])
def test_non_positive_crossbeam_section(finger, which):
    values = np.asarray(getattr(finger.crossbeams, which)).copy()
    values[4] = -0.25
    _raises(_crossbeams(finger, **{which: values}), _cb_field(which, 4), "-0.25")


@pytest.mark.parametrize("name", ["front_base", "back_base", "tip"])
def test_point_with_wrong_shape(finger, name):
    bad = eqx.tree_at(lambda f: getattr(f, name), finger, np.array([1.0, 2.0, 3.0]))
    _raises(bad, name, "[1.0, 2.0, 3.0]")


def test_zero_length_beams(finger):
    _raises(
        eqx.tree_at(lambda f: f.front_base, finger, np.array([0.0, 120.0])), "front", "zero length"
    )
    _raises(
        eqx.tree_at(lambda f: f.back_base, finger, np.array([0.0, 120.0])), "back", "zero length"
    )


def test_coincident_bases(finger):
    _raises(
        eqx.tree_at(lambda f: f.back_base, finger, np.array([0.0, 0.0])), "front_base", "back_base"
    )


def test_unknown_torsion(finger):
    with pytest.raises(fr.FingerError, match="torsion must be one of .*, got 'circle'"):
        dataclasses.replace(finger, torsion="circle")


@pytest.mark.parametrize("field", ["front_base", "back_base"])
def test_unknown_base(field):
    with pytest.raises(fr.FingerError, match=f"adaptor.{field} must be one of .*, got 'welded'"):
        fr.Adaptor(**{field: "welded"})


def test_a_choice_by_name_is_deprecated_and_means_its_object():
    with pytest.deprecated_call(match="PinnedBase"):
        adaptor = fr.Adaptor(front_base="pinned")
    assert adaptor.front_base == fr.PinnedBase()
    with pytest.deprecated_call(match="SaintVenantTorsion"):
        assert (
            fr.solve_cantilever(
                10.0, fr.Material(2.0, 0.4), fr.Section(1.0, 5.0), torsion="rectangle"
            ).result
            is not None
        )
    with pytest.deprecated_call(match="DenseLinearSolver"):
        options = fr.SolverOptions(linear_solver="dense")
    assert options.linear_solver == fr.DenseLinearSolver()
    with pytest.deprecated_call(match="StepBackend"):
        assert fr.Integrator(backend="step").backend == fr.StepBackend()


@pytest.mark.parametrize("s", [0.0, -5.0, 120.0, 130.0])
def test_crossbeam_front_attachment_outside_front_beam(finger, s):
    fs = np.asarray(finger.crossbeams.front_s).copy()
    i = 0 if s <= 0 else 6
    fs[i] = s
    _raises(_crossbeams(finger, front_s=fs), f"crossbeams[{i}].front_s", repr(s), "front beam")


@pytest.mark.parametrize("s", [0.0, -1.0, float(np.hypot(40.0, 120.0)), 200.0])
def test_crossbeam_back_attachment_outside_back_beam(finger, s):
    bs = np.asarray(finger.crossbeams.back_s).copy()
    i = 0 if s <= 0 else 6
    bs[i] = s
    _raises(_crossbeams(finger, back_s=bs), f"crossbeams[{i}].back_s", repr(s), "back beam")


def test_crossing_crossbeams(finger):
    bs = np.asarray(finger.crossbeams.back_s).copy()
    bs[2], bs[3] = bs[3], bs[2]  # crossbeams 2 and 3 now cross
    _raises(_crossbeams(finger, back_s=bs), "crossbeams 2 and 3", "cross")


def test_crossbeams_sharing_a_front_point(finger):
    fs = np.asarray(finger.crossbeams.front_s).copy()
    fs[1] = fs[0]
    _raises(_crossbeams(finger, front_s=fs), "crossbeams 0 and 1", repr(float(fs[0])))


def test_crossbeams_listed_tip_to_base(finger):
    cb = finger.crossbeams
    rev = {k: np.asarray(getattr(cb, k))[::-1] for k in ("front_s", "back_s", "thickness", "depth")}
    _raises(_crossbeams(finger, **rev), "base to tip", "crossbeams[1].front_s")


NO_CROSSBEAMS = fr.Crossbeams(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))


def _main_beams(finger, crossbeams=NO_CROSSBEAMS, **kw):
    """ref-A with other main-beam fields (and, by default, no crossbeams)."""
    return dataclasses.replace(finger, crossbeams=crossbeams, **kw)


@pytest.mark.parametrize("back_base", [(0.0, 10.0), (0.0, 60.0), (1.0, 0.0), (-0.5, 30.0)])
def test_back_base_on_or_near_the_front_beam(finger, back_base):
    # (0, 10): the back beam runs along the front beam from z = 10 to the tip; the solve
    # "converged" to dx = 49.6 mm before this rule. Within (1.5 + 1.5) / 2 = 1.5 mm of the
    # front beam's centreline is refused as well. The crossbeams are kept: the beams
    # are refused before them.
    bad = _main_beams(finger, finger.crossbeams, back_base=np.array(back_base))
    where = "lies on" if back_base[0] == 0.0 else f"lies {abs(back_base[0]):.4g} mm from"
    _raises(bad, f"back_base = {list(back_base)}", where, "front beam's centreline", "1.5 mm")


def test_base_too_close_names_both_thicknesses(finger):
    """A base far from the other beam but thicker than the gap: the message names the two
    thickness fields, not only the base."""
    thick = _main_beams(finger, front=fr.Section(30.0, 20.0), back=fr.Section(60.0, 20.0))
    _raises(
        thick,
        "back_base = [40.0, 0.0] lies 40 mm from the front beam's centreline",
        "at least 45 mm",
        "half of back.thickness = 60 mm at the base plus half of front.thickness = 30 mm",
    )


def test_front_base_on_the_back_beam(finger):
    # Collinear beams, the back base below the front base: the back beam runs through
    # the front beam's base and along it (a crossbeam could then join coincident points).
    bad = _main_beams(finger, back_base=np.array([0.0, -10.0]))
    _raises(bad, "front_base = [0.0, 0.0]", "lies on the back beam's centreline", "at back s = 10")


@pytest.mark.parametrize("kappa", [0.01, 0.015])
def test_back_beam_crossing_the_front_beam(finger, kappa):
    # Precurved toward the front beam, the back beam's arc crosses it (at z = 49 and 13.3)
    # and comes back to the tip.
    bad = _main_beams(finger, finger.crossbeams, back_curvature=kappa)
    _raises(bad, "back beam crosses the front beam", f"back_curvature = {kappa}", "only at the tip")


@pytest.mark.parametrize("back_base", [(2.0, 0.0), (5.0, 0.0)])
def test_main_beams_too_close_away_from_the_tip(finger, back_base):
    # A 2 or 5 mm wide base: the 1.5 mm beams overlap over more than the last quarter of
    # the front beam (30 mm).
    bad = _main_beams(finger, back_base=np.array(back_base))
    _raises(bad, "centrelines come within", "of each other", "last 30 mm", "at least 1.5 mm")


@pytest.mark.parametrize(
    "kw",
    [
        dict(back_base=np.array([-40.0, 0.0])),  # mirrored
        dict(back_base=np.array([40.0, -20.0])),
        dict(back_base=np.array([6.5, 0.0])),  # narrow, overlapping only near the tip
        dict(front_curvature=0.004, back_curvature=-0.003),
        dict(back_curvature=0.005),  # nearly tangent at the tip, not crossing
        dict(front=fr.Section(1.5, 20.0, tip_thickness=3.0)),
    ],
)
def test_main_beams_meeting_only_at_the_tip_are_accepted(finger, kw):
    fr.validate_finger(_main_beams(finger, **kw))


def test_round_trip_finger_of_test_toml_is_accepted():
    fr.validate_finger(round_trip_finger())


def test_short_crossbeam(finger):
    # Near the tip the main beams may come close; a crossbeam there still needs a length
    # of at least half the sum of the main beams' half thicknesses, (0.75 + 0.75) / 2.
    lb = float(np.hypot(40.0, 120.0))
    cb = fr.Crossbeams(
        [117.0, 119.5], [lb * 117.0 / 120.0, lb * 119.5 / 120.0], [1.0] * 2, [20.0] * 2
    )
    _raises(_crossbeams(finger, **vars(cb)), "crossbeams[1]", "0.1667 mm long", "0.75 mm")
    fr.validate_finger(_crossbeams(finger, **{k: v[:1] for k, v in vars(cb).items()}))  # 1 mm


@pytest.mark.parametrize(
    "field,value",
    [("front_s", np.zeros((7, 1)) + 15.0), ("thickness", np.ones(6)), ("depth", np.float64(20.0))],
)
def test_crossbeam_arrays_with_wrong_shapes(finger, field, value):
    _raises(_crossbeams(finger, **{field: value}), "crossbeam arrays", "shapes", field)


# --- adaptor -------------------------------------------------------------------------


@pytest.mark.parametrize("beam", ["front", "back"])
@pytest.mark.parametrize("kind", ["pinned", "free"])
def test_clamp_length_needs_clamped_base(finger, beam, kind):
    base = {"pinned": fr.PinnedBase(), "free": fr.FreeBase()}[kind]
    bad = _adaptor(finger, **{f"{beam}_base": base, f"{beam}_clamp_length": 12.5})
    _raises(bad, f"adaptor.{beam}_clamp_length", "12.5", f"'{kind}'")


@pytest.mark.parametrize("beam,value", [("front", -1.0), ("front", 120.0), ("back", 130.0)])
def test_clamp_length_out_of_range(finger, beam, value):
    _raises(
        _adaptor(finger, **{f"{beam}_clamp_length": value}),
        f"adaptor.{beam}_clamp_length",
        repr(value),
    )


def test_clamp_length_in_range_is_accepted(finger):
    fr.validate_finger(_adaptor(finger, front_clamp_length=0.0, back_clamp_length=40.0))


# --- loads ---------------------------------------------------------------------------


@pytest.mark.parametrize("beam", [9, -1, 100])
def test_load_on_no_beam(finger, beam):
    bad = finger.with_loads(fr.PointLoad(beam, 10.0, (0.05, 0.0, 0.0)))
    _raises(bad, "loads[0].beam", repr(beam))


def test_load_beam_must_be_an_int(finger):
    bad = finger.with_loads(fr.PointLoad(1.0, 10.0, (0.05, 0.0, 0.0)))
    _raises(bad, "loads[0].beam", "1.0")


@pytest.mark.parametrize("beam,s", [(0, 0.0), (0, -3.0), (0, 120.5), (1, 127.0), (2, 36.0)])
def test_point_load_outside_its_beam(finger, beam, s):
    # crossbeam 0 (beam 2) is 40 (1 - 15/120) = 35 mm long.
    bad = finger.with_loads(finger.loads[0], fr.PointLoad(beam, s, (0.05, 0.0, 0.0)))
    _raises(bad, "loads[1].s", repr(s))


# A load inside a clamped length (the adaptor carries it) is valid, with a warning.


def _clamp_warning(finger, *fragments):
    """validate_finger(finger) warns once with a FingerWarning holding every fragment,
    attributed to the caller's line (here, this file)."""
    with pytest.warns(fr.FingerWarning) as record:
        fr.validate_finger(finger)
    assert len(record) == 1, [str(w.message) for w in record]
    msg = str(record[0].message)
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    assert record[0].filename == __file__
    return msg


@pytest.mark.parametrize("s", [5.0, 10.0])
def test_point_load_inside_the_back_clamp_warns(finger, s):
    f = _adaptor(finger, back_clamp_length=10.0).with_loads(
        finger.loads[0], fr.PointLoad(1, s, (0.05, 0.0, 0.0))
    )
    msg = _clamp_warning(f, f"loads[1] (beam back, s = {s})", "back beam's clamped length 10.0")
    assert "adaptor.back_clamp_length" in msg and "the adaptor carries it" in msg


def test_point_load_inside_the_front_clamp_warns(finger):
    f = _adaptor(finger, front_clamp_length=20.0).with_loads(
        fr.PointLoad(0, 12.5, (0.05, 0.0, 0.0))
    )
    _clamp_warning(f, "loads[0] (beam front, s = 12.5)", "front beam's clamped length 20.0")


def test_distributed_load_inside_a_clamp_warns(finger):
    clamped = _adaptor(finger, back_clamp_length=10.0)
    inside = clamped.with_loads(fr.DistributedLoad(1, (2.0, 8.0), (0.05, 0.0, 0.0)))
    _clamp_warning(inside, "loads[0] (beam back, s_range = [2.0, 8.0]) lies inside", "10.0")
    partly = clamped.with_loads(fr.DistributedLoad(1, (5.0, 30.0), (0.05, 0.0, 0.0)))
    _clamp_warning(partly, "s_range = [5.0, 30.0]) lies partly inside", "part on [5.0, 10.0]")


def test_loads_outside_the_clamps_do_not_warn(finger):
    f = _adaptor(finger, front_clamp_length=5.0, back_clamp_length=10.0).with_loads(
        fr.PointLoad(1, 10.5, (0.05, 0.0, 0.0)),
        fr.DistributedLoad(1, (10.0, 30.0), (0.05, 0.0, 0.0)),  # starts at the clamp's end
        fr.PointLoad(2, 1.0, (0.05, 0.0, 0.0)),  # a crossbeam is never clamped
        fr.PointLoad(0, 60.0, (0.05, 0.0, 0.0)),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error", fr.FingerWarning)
        fr.validate_finger(f)
        fr.validate_finger(finger.with_loads(fr.PointLoad(1, 5.0, (0.05, 0.0, 0.0))))  # no clamp
    assert issubclass(fr.FingerWarning, UserWarning)


def test_finger_file_with_a_load_in_the_clamp_warns():
    from finray_jax import io as fio

    text = (EXAMPLES / "ref_a.toml").read_text()
    text = text.replace("[adaptor]", "[adaptor]\nback_clamp_length = 10.0", 1)
    text += '\n[[loads]]\nkind = "point"\nbeam = "back"\ns = 5.0\nforce = [0.05, 0.0, 0.0]\n'
    with pytest.warns(fr.FingerWarning, match=re.escape("loads[1] (beam back, s = 5.0)")):
        fio.loads_finger(text)


def test_point_load_at_the_tip_is_accepted(finger):
    fr.validate_finger(finger.with_loads(fr.PointLoad(0, 120.0, (0.05, 0.0, 0.0))))


@pytest.mark.parametrize("s_range", [(105.0, 75.0), (80.0, 80.0), (-1.0, 30.0), (100.0, 121.0)])
def test_distributed_load_range(finger, s_range):
    bad = finger.with_loads(fr.DistributedLoad(0, s_range, (1.0, 0.0, 0.0)))
    _raises(bad, "loads[0].s_range", f"[{s_range[0]}, {s_range[1]}]")


def test_unknown_load_type(finger):
    class Gust(fr._finger.AbstractLoad):
        beam: int = eqx.field(static=True, default=0)

    _raises(finger.with_loads(Gust()), "loads[0]", "Gust")


# Shapes of load and section values. A force given as an (x, z) pair, like the points,
# is a natural mistake; validation must name it rather than pass it on to the solver
# (where it fails with a broadcasting error, or not at all).


def test_point_load_force_with_wrong_shape(finger):
    bad = finger.with_loads(fr.PointLoad(0, 60.0, (0.05, 0.0)))
    _raises(bad, "loads[0].force", "0.05")


def test_point_load_moment_with_wrong_shape(finger):
    bad = finger.with_loads(fr.PointLoad(0, 60.0, (0.05, 0.0, 0.0), (0.0, 1.0)))
    _raises(bad, "loads[0].moment")


def test_distributed_load_force_with_wrong_shape(finger):
    bad = finger.with_loads(fr.DistributedLoad(0, (75.0, 105.0), (1.0, 0.0)))
    _raises(bad, "loads[0].total_force")


def test_distributed_load_range_with_wrong_shape(finger):
    bad = finger.with_loads(fr.DistributedLoad(0, (75.0, 90.0, 105.0), (1.0, 0.0, 0.0)))
    _raises(bad, "loads[0].s_range")


def test_section_thickness_with_wrong_shape(finger):
    bad = eqx.tree_at(lambda f: f.front, finger, fr.Section(np.array([1.5, 1.5]), 20.0))
    _raises(bad, "front.thickness")


# --- the entry points check before compiling ---------------------------------------------


def test_solve_finger_validates_eagerly(finger):
    bad = _material(finger, E=-1.0)
    with pytest.raises(fr.FingerError, match="material.E"):
        fr.solve_finger(bad)
    with pytest.raises(fr.FingerError, match="material.E"):
        fr.limit_load(bad)


@pytest.mark.parametrize("func", [fr.solve_finger, fr.limit_load, fr.topology_of])
def test_unknown_mode(finger, func):
    with pytest.raises(ValueError, match="mode.*'bad'"):
        func(finger, mode="bad")


def test_solve_finger_needs_a_finger():
    with pytest.raises(TypeError, match="Finger"):
        fr.solve_finger({"E": 12.0})


@pytest.mark.parametrize("steps", [0, -3, 2.5])
def test_integrator_steps(steps):
    with pytest.raises(
        ValueError, match=re.escape("Integrator.steps") + ".*" + re.escape(repr(steps))
    ):
        fr.Integrator(steps=steps)


def test_integrator_backend():
    with pytest.raises(ValueError, match="Integrator.backend.*'rk4'"):
        fr.Integrator(backend="rk4")


@pytest.mark.parametrize(
    "field,value",
    [
        ("rtol", -1),
        ("atol", 0.0),
        ("min_arc_step", -1e-3),
        ("initial_arc_step", "big"),
        ("reuse_jacobian_below", 0.0),
        ("reuse_jacobian", "yes"),
        ("rtol", 1e6),  # (accepted any iterate: a "converged" wrong answer)
        ("atol", 1.0),
    ],
)
def test_solver_options_tolerances(field, value):
    with pytest.raises(ValueError, match=f"SolverOptions.{field}.*{re.escape(repr(value))}"):
        fr.SolverOptions(**{field: value})


@pytest.mark.parametrize("field,value", [("max_newton_steps", 0), ("max_continuation_steps", 2.0)])
def test_solver_options_counts(field, value):
    with pytest.raises(ValueError, match=f"SolverOptions.{field}.*{re.escape(repr(value))}"):
        fr.SolverOptions(**{field: value})


def test_solver_options_arc_steps_in_order():
    with pytest.raises(ValueError, match=r"min_arc_step <= initial_arc_step <= max_arc_step.*1.0"):
        fr.SolverOptions(min_arc_step=1.0, max_arc_step=0.1)


def test_planar_mode_refuses_an_out_of_plane_load(finger):
    """Planar mode would drop a y force or an x / z moment: asked for, it is refused."""
    y_force = fr.PointLoad(beam=0, s=60.0, force=(0.05, 0.05, 0.0))
    twist = fr.PointLoad(beam=0, s=60.0, force=(0.05, 0.0, 0.0), moment=(0.0, 0.0, 1.0))
    for load, frag in ((y_force, "loads[0].force"), (twist, "loads[0].moment")):
        f = dataclasses.replace(finger, loads=(load,))
        _raises(f, frag, "mode 'planar'", func=lambda f: fr.topology_of(f, "planar"))
        assert fr.topology_of(f).mode == "spatial"  # (auto)


def test_cantilever_arguments():
    m, sec = fr.Material(12.0, 0.45), fr.Section(1.5, 20.0)
    with pytest.raises(ValueError, match="length.*-1.0"):
        fr.solve_cantilever(-1.0, m, sec)
    with pytest.raises(ValueError, match="mode.*'auto'"):
        fr.solve_cantilever(100.0, m, sec, mode="auto")


@pytest.mark.parametrize(
    "field, value", [("slope_tol", 0.0), ("step_tol", -1.0), ("max_secant_steps", 0)]
)
def test_fold_options_name_the_bad_field(field, value):
    from finray_jax import FoldOptions

    with pytest.raises(ValueError, match=f"FoldOptions.{field} must be"):
        FoldOptions(**{field: value})


@pytest.mark.parametrize("thickness", [15.0, 40.0])
def test_crossbeams_thicker_than_their_spacing_are_refused(finger, thickness):
    """Neighbouring crossbeams whose footprints on a main beam overlap (thickness over
    the sine of their angle to it, against the spacing of their attachments) are one
    solid block, not two crossbeams: refused, naming both and their thicknesses."""
    t = np.asarray(finger.crossbeams.thickness).copy()
    t[:2] = thickness
    spacing = float(np.diff(np.asarray(finger.crossbeams.front_s))[0])
    assert thickness >= spacing  # (ref-A's crossbeams are 15 mm apart on the front beam)
    _raises(
        _crossbeams(finger, thickness=t),
        "crossbeams 0 and 1 overlap where they meet the front beam",
        "crossbeams[0].thickness",
        f"{thickness:.4g}",
    )


def test_crossbeams_just_clear_of_each_other_are_accepted(finger):
    t = np.asarray(finger.crossbeams.thickness).copy()
    t[:2] = 5.0  # far below the 15 mm spacing, at ref-A's angles
    fr.validate_finger(_crossbeams(finger, thickness=t))
