"""Grasping against an independent established solver: an openseespy contact model.

Finger-1 (examples/grasp_finger1.toml, original adaptor; grasp_finger1_modified.toml,
front base pinned, back beam clamped over 20 mm and backed by a rigid support to 60 mm)
closing 2, 4 and 6 mm on the 18 mm cylinder. The reference comes from
tests/reference/opensees_grasp.py (2-D corotational forceBeamColumn frame, gap elements
with the same C1 penalty law at the same k and delta, mesh refined to 0.039 mm) and is
stored in tests/data/grasp_opensees.json, so the default suite runs without openseespy.
The `opensees`-marked test re-runs its two coarsest meshes.

Both sides solve the same model: the same penalty k (the reference stores finray_jax's
`grasp(...).stiffness` of each case, which the modified adaptor's grasp raises to keep
the penetration below 2 % of the front beam's thickness; here the grasp is solved at that
k with `stiffen=False`), the same delta, the same support line (the back beam's base
centreline along its undeformed tangent, gap = distance, no half-thickness).

Tolerance: 1 % of the reference value, as the issue asks, with two floors:
* the reference's own error band, 3 x its Richardson mesh-error estimate (stored per
  output; at most 0.02 % of the quantities' scales on the finest mesh);
* 0.1 % of the quantity's scale (forces: the case's normal force; tip displacements: the
  tip displacement's magnitude; moments: the larger base moment), for components far
  smaller than their scale, e.g. the original adaptor's contact force Fz (1e-3 of the
  normal force), where 1 % of the component is below either side's discretisation (the
  finray grasp integrates 0.3 mm steps: its normal force moves by 3e-5 relative from 16
  to 128 steps, docs/grasping.md; the reference's penalty lumping at nodes converges as h^2).

Measured (finray_jax vs the finest reference mesh; rel = (ours - theirs) / theirs, or /
scale where marked *):

    case        d   output              ours          theirs        rel
    (filled in below by the measured run)
"""

import json
import pathlib
import subprocess
import sys

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import finray_jax as fr
from finray_jax.io import load_finger

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = pathlib.Path(__file__).parent / "data" / "grasp_opensees.json"
REF = json.loads(DATA.read_text())
FILES = {"original": "grasp_finger1.toml", "modified": "grasp_finger1_modified.toml"}
CLOSINGS = (2.0, 4.0, 6.0)
REL = 0.01  # the 1 %
FLOOR = 1e-3  # of the quantity's scale (see the module docstring)
MESH = 3.0  # x the reference's Richardson mesh-error estimate


def _at_stiffness(finger, k):
    return eqx.tree_at(
        lambda f: f.contact.stiffness, finger, jnp.asarray(k), is_leaf=lambda x: x is None
    )


@pytest.fixture(scope="module")
def grasps():
    """finray_jax's grasp of every case, at the reference's penalty stiffness."""
    out = {}
    for adaptor, name in FILES.items():
        finger, _ = load_finger(ROOT / "examples" / name)
        for d in CLOSINGS:
            k = REF[adaptor][f"{d:g}"]["k"]
            g = fr.grasp(_at_stiffness(finger, k), closing=d, stiffen=False)
            assert g.converged, (adaptor, d, g.solution.message)
            assert float(g.stiffness) == k
            out[adaptor, d] = g
    return out


def _ours(g):
    """Our outputs under the reference's names and sign conventions."""
    c, s = g.contact, g.solution
    out = {
        "contact_force.Fx": c.force[0],
        "contact_force.Fz": c.force[2],
        "normal_force": c.normal_force,
        "tip.dx": s.tip.displacement[0],
        "tip.dz": s.tip.displacement[2],
        "tip.rotation": -s.tip.rotation[1],  # the reference's is CCW in (x, z): about -y
        "support_force.Fx": c.support_force[0],
        "support_force.Fz": c.support_force[2],
    }
    for name, r in (("front", s.reactions_front), ("back", s.reactions_back)):
        out[f"reactions.{name}.Fx"] = r.force[0]
        out[f"reactions.{name}.Fz"] = r.force[2]
        out[f"reactions.{name}.My_ccw"] = -r.moment[1]
    return {k: float(v) for k, v in out.items()}


def _get(tree, name):
    for p in name.split("."):
        tree = tree[p]
    return tree


def _scale(ref, name):
    if name.startswith("tip.rotation"):
        return abs(ref["tip"]["rotation"])
    if name.startswith("tip."):
        return float(np.hypot(ref["tip"]["dx"], ref["tip"]["dz"]))
    if name.endswith("My_ccw"):
        return max(abs(ref["reactions"][b]["My_ccw"]) for b in ("front", "back"))
    return ref["normal_force"]


def _compare(g, adaptor, d):
    """Rows (output, ours, theirs, difference, tolerance) of one case."""
    ref = REF[adaptor][f"{d:g}"]
    rows = []
    for name, ours in _ours(g).items():
        theirs = _get(ref, name)
        band = MESH * _get(ref["mesh_error"], name)
        tol = max(REL * abs(theirs), FLOOR * _scale(ref, name), band)
        rows.append((name, ours, theirs, ours - theirs, tol))
    return rows


def _fmt_rel(ours, theirs, scale):
    if abs(theirs) >= 0.1 * scale and theirs != 0:
        return f"{(ours - theirs) / abs(theirs):+.2e}"
    return f"{(ours - theirs) / scale:+.2e}*" if scale else "-"


def test_comparison_table(grasps, capsys):
    """The full table (printed: run with -s)."""
    lines = [f"{'case':10s} {'d':>3s}  {'output':24s} {'ours':>13s} {'theirs':>13s} {'rel':>10s}"]
    for (adaptor, d), g in grasps.items():
        ref = REF[adaptor][f"{d:g}"]
        for name, ours, theirs, _, _ in _compare(g, adaptor, d):
            if adaptor == "original" and name.startswith("support"):
                continue
            rel = _fmt_rel(ours, theirs, _scale(ref, name))
            lines.append(
                f"{adaptor:10s} {d:3g}  {name:24s} {ours:13.6g} {theirs:13.6g} {rel:>10s}"
            )
    with capsys.disabled():
        print("\n" + "\n".join(lines))


@pytest.mark.parametrize("d", CLOSINGS)
@pytest.mark.parametrize("adaptor", ["original", "modified"])
@pytest.mark.parametrize(
    "group",
    ["contact_force", "normal_force", "tip", "reactions", "support_force"],
)
def test_grasp_matches_opensees(grasps, adaptor, d, group):
    bad = [
        f"{name}: ours {ours:.6g} theirs {theirs:.6g} diff {diff:.3g} > {tol:.3g}"
        for name, ours, theirs, diff, tol in _compare(grasps[adaptor, d], adaptor, d)
        if name.startswith(group) and not abs(diff) <= tol
    ]
    assert not bad, bad


def test_reference_is_converged_and_consistent():
    """The stored reference's own checks: mesh error far inside the 1 % band, the finger
    in equilibrium, the penalty law reproduced, no untracked node touching the cylinder."""
    for adaptor in FILES:
        for d in CLOSINGS:
            ref = REF[adaptor][f"{d:g}"]
            for name in _flat_names():
                err = _get(ref["mesh_error"], name)
                assert err <= 2e-3 * _scale(ref, name), (adaptor, d, name, err)
            eq = ref["equilibrium_residual"]
            assert abs(eq["Fx"]) < 1e-9 and abs(eq["Fz"]) < 1e-9
            assert ref["penalty_law_max_error_N"] < 1e-5
            assert ref["clearance_of_other_nodes_mm"] > 1.0


def _flat_names():
    out = ["contact_force.Fx", "contact_force.Fz", "normal_force", "tip.dx", "tip.dz"]
    out += ["tip.rotation", "support_force.Fx", "support_force.Fz"]
    out += [f"reactions.{b}.{q}" for b in ("front", "back") for q in ("Fx", "Fz", "My_ccw")]
    return out


@pytest.mark.opensees
@pytest.mark.slow
def test_stored_reference_is_reproducible(tmp_path):
    """Re-run the openseespy script's two coarsest meshes (needs the `bench` extra) and
    compare with the stored convergence tables."""
    pytest.importorskip("openseespy")
    out = tmp_path / "grasp.json"
    script = pathlib.Path(__file__).parent / "reference" / "opensees_grasp.py"
    subprocess.run([sys.executable, str(script), "--quick", "--out", str(out)], check=True)
    new = json.loads(out.read_text())
    for adaptor in FILES:
        for d in CLOSINGS:
            a = new[adaptor][f"{d:g}"]["convergence"]
            b = REF[adaptor][f"{d:g}"]["convergence"][: len(a)]
            assert [r["h"] for r in a] == [r["h"] for r in b] == [1.25, 0.625]
            for ra, rb in zip(a, b):
                for name in _flat_names():
                    assert abs(ra[name] - rb[name]) <= 1e-9 + 1e-7 * abs(rb[name]), (
                        adaptor,
                        d,
                        ra["h"],
                        name,
                        ra[name],
                        rb[name],
                    )
