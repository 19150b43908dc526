"""ref-A against an independent established solver: an openseespy corotational frame.

The reference answers come from tests/reference/opensees_ref_a.py (2-D forceBeamColumn,
corotational transformation, elastic + Timoshenko shear section, 2432 elements of
0.156 mm) and are stored in tests/data/ref_a_opensees.json, so the default suite runs
without openseespy. The `opensees`-marked test re-runs it.

Where the tolerances come from (the reference's own error, from its stored tables):
- its mesh error is O(h^2); the finest mesh against the h^2-Richardson extrapolation of
  the last two meshes ("tip_richardson_h2_extrapolated") differs by at most 1.8e-5 of the
  tip displacement (L2; L1 3.6e-6, L3 1.7e-5, and the same for k = 1), by 4.6e-4 mm in
  L2's tip x, and by 4.8e-5 of the limit loads ("..._richardson_h2");
- the back beam's stored shape is interpolated linearly between nodes 0.165 mm apart,
  off by at most 1.8e-4 mm ("back_interpolation_max_diff_mm").
So the tip is compared within 0.05 %, the shapes within 0.01 mm, the limit loads within
0.05 %: each at least 10x the reference's own error. Our integration error at the default
10 steps per segment is 5e-6 of the tip at most (L2, README), below all of these.
Our shape is sampled at the reference's arc lengths by a cubic spline through the points of
each integration segment (1.5 mm apart): linear interpolation there would be off by
h^2 kappa / 8 ~ 0.01 mm on L2, as large as the tolerance.
"""

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from helpers import segment_slices
from scipy.interpolate import CubicSpline

import finray_jax as fr

DATA = pathlib.Path(__file__).parent / "data" / "ref_a_opensees.json"
REF = json.loads(DATA.read_text())

TIP_RTOL = 5e-4  # 0.05 %: 28x the reference's largest mesh error on the tip (1.8e-5)
SHAPE_ATOL = 0.01  # mm: 20x its mesh error in L2's tip x, 50x its back-beam interpolation
REACTION_RTOL = 1e-3  # 0.1 % of each reaction component
LIMIT_RTOL = 5e-4  # 0.05 %: 10x its mesh error on the limit loads (4.8e-5)


@pytest.fixture(scope="module")
def solutions():
    return {
        case: fr.solve_finger(fr.ref_finger_a(case), mode="planar") for case in ("L1", "L2", "L3")
    }


def _sample(beam, s_query):
    """(x, z) of a BeamSolution at arc lengths s_query: a cubic spline through the points of
    the integration segment holding each query (the solution is smooth inside a segment;
    its slope may jump at a cut, where a point load or a crossbeam acts)."""
    s, p = np.asarray(beam.s), np.asarray(beam.position)[:, [0, 2]]
    out = np.full((len(s_query), 2), np.nan)
    for sl in segment_slices(beam, -np.inf, np.inf):
        inside = (s_query >= s[sl][0] - 1e-12) & (s_query <= s[sl][-1] + 1e-12)
        out[inside] = CubicSpline(s[sl], p[sl])(s_query[inside])
    assert not np.isnan(out).any(), "a query lies outside every segment"
    return out[:, 0], out[:, 1]


def _assert_tip_matches(sol, ref):
    ours = np.asarray(sol.tip.displacement)[[0, 2]]
    theirs = np.array([ref["dx"], ref["dz"]])
    rel = np.linalg.norm(ours - theirs) / np.linalg.norm(theirs)
    assert rel < TIP_RTOL, (ours, theirs, rel)
    rot = float(sol.tip.rotation[1])
    assert abs(rot - ref["rotation_about_y"]) < TIP_RTOL * abs(ref["rotation_about_y"]), rot


@pytest.mark.parametrize("case", ["L1", "L2", "L3"])
def test_tip_matches_opensees(solutions, case):
    sol = solutions[case]
    assert sol.status == "converged"
    _assert_tip_matches(sol, REF["k_5_6"][case]["tip"])


@pytest.mark.parametrize("case", ["L1", "L2", "L3"])
@pytest.mark.parametrize("beam", ["front", "back"])
def test_shape_matches_opensees(solutions, case, beam):
    ref = REF["k_5_6"][case][beam]
    x, z = _sample(getattr(solutions[case], beam), np.asarray(ref["s"]))
    err = np.hypot(x - np.asarray(ref["x"]), z - np.asarray(ref["z"]))
    assert np.max(err) < SHAPE_ATOL, err


@pytest.mark.parametrize("case", ["L1", "L2", "L3"])
def test_reactions_match_opensees(solutions, case):
    """Every base-reaction component within 0.1 % of its own size (not of the applied
    load, which would let the small components go unchecked). The reference stores no
    mesh table for the reactions; 0.1 % is 50x its largest tip mesh error."""
    sol = solutions[case]
    ref = REF["k_5_6"][case]["reactions"]
    for name, r in (("front", sol.reactions_front), ("back", sol.reactions_back)):
        theirs = ref[name]
        my = -theirs["My_ccw"]  # our moment is about +y
        pairs = (
            (float(r.force[0]), theirs["Fx"]),
            (float(r.force[2]), theirs["Fz"]),
            (float(r.moment[1]), my),
        )
        for ours, value in pairs:
            assert abs(ours - value) < REACTION_RTOL * abs(value), (case, name, ours, value)


def test_shear_coefficient_one_matches_opensees():
    """The paper's k = 1 against the k = 1 reference, with the tolerances above (its mesh
    error on the tip is 3.6e-6 on L1)."""
    sol = fr.solve_finger(fr.ref_finger_a("L1", shear_coefficient=1.0), mode="planar")
    assert sol.status == "converged"
    ref = REF["k_1"]["L1"]
    _assert_tip_matches(sol, ref["tip"])
    for beam in ("front", "back"):
        x, z = _sample(getattr(sol, beam), np.asarray(ref[beam]["s"]))
        err = np.hypot(x - np.asarray(ref[beam]["x"]), z - np.asarray(ref[beam]["z"]))
        assert np.max(err) < SHAPE_ATOL, (beam, err)
    # The k = 1 and k = 5/6 references' tips differ by 1.5e-3 of the tip (3x the
    # tolerance), so a solve that ignored k could not pass both.
    tip = lambda t: np.array([t["dx"], t["dz"]])
    k1, k56 = tip(ref["tip"]), tip(REF["k_5_6"]["L1"]["tip"])
    assert np.linalg.norm(k1 - k56) > 2 * TIP_RTOL * np.linalg.norm(k56)


@pytest.mark.parametrize(
    "case,key,magnitude", [("L2", "point_s60", 1.5), ("L3", "distributed_75_105", 1.0)]
)
def test_limit_load_matches_opensees(case, key, magnitude):
    lim = fr.limit_load(fr.ref_finger_a(case), mode="planar")
    assert lim.solution.status == "converged"
    ours = float(lim.load_factor) * magnitude
    theirs = REF["k_5_6"]["limit_loads"][key]
    assert abs(ours - theirs) < LIMIT_RTOL * theirs, (ours, theirs)


@pytest.mark.opensees
@pytest.mark.slow
def test_stored_reference_is_reproducible(tmp_path):
    """Re-run the openseespy script (needs the `bench` extra) for the block every test here
    compares with (k = 5/6 on the finest mesh, the three load cases) and find the stored
    tips, shapes and reactions again: the same program on the same inputs, so equal to
    1e-9 (relative; UmfPack's and the platform's rounding aside)."""
    pytest.importorskip("openseespy")
    out = tmp_path / "ref.json"
    script = pathlib.Path(__file__).parent / "reference" / "opensees_ref_a.py"
    fine = str(REF["element_size"])
    argv = ["--out", str(out), "--blocks", "k_5_6", "--sizes", fine, "--no-limit", "--no-checks"]
    subprocess.run([sys.executable, str(script), *argv], check=True)
    new = json.loads(out.read_text())["k_5_6"]
    for case in ("L1", "L2", "L3"):
        a, b = new[case], REF["k_5_6"][case]
        for key in ("tip", "reactions"):
            got, want = _numbers(a[key]), _numbers(b[key])
            assert got.keys() == want.keys()
            for name, value in want.items():
                assert abs(got[name] - value) < 1e-9 + 1e-9 * abs(value), (case, name)
        for beam in ("front", "back"):
            for xz in ("x", "z"):
                np.testing.assert_allclose(a[beam][xz], b[beam][xz], rtol=0, atol=1e-9)


def _numbers(tree, prefix="") -> dict:
    """The numbers of a nested JSON dict, by their dotted path."""
    out = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            out.update(_numbers(v, f"{prefix}{k}."))
        elif isinstance(v, (int, float)):
            out[prefix + k] = float(v)
    return out
