"""Independent reference for grasping: Finger-1 closing on a rigid cylinder, with OpenSees.

Run:  python tests/reference/opensees_grasp.py --out tests/data/grasp_opensees.json
      (--quick: only the two coarsest meshes and no penalty study, for a reproducibility test)

Model (units mm, N, MPa; the conventions of opensees_ref_a.py)
---------------------------------------------------------------
* 2-D OpenSees model (ndm=2, ndf=3), OpenSees X = x, OpenSees Y = z, rotation CCW
  positive in (x, z) viewed with x right and z up.  The sections, element and
  transformation are opensees_ref_a.py's (imported, not copied): forceBeamColumn, 3-point
  Gauss-Lobatto, geomTransf Corotational, elastic (E, A, I) section aggregated with an
  elastic shear law k G A, k = 5/6 (Timoshenko).
* Finger-1 (examples/finger1.toml): front beam (0,0)->(0,120), back beam (40,0)->(0,120),
  one shared tip node; seven horizontal crossbeams at z = 15, 30, ..., 105 sharing the main
  beams' nodes (rigid joints, centreline to centreline).  Thickness 3.0 (front, back) and
  2.0 (crossbeams), depth 20, E = 12, nu = 0.45.  No distributed load: only the object.
* Mesh: uniform elements of size h on the front beam (nodes at every 15 mm); the back
  beam is cut at the crossbeams, at l_c = 20 and at l_s = 60 and each piece split into
  elements no longer than h L_back / 120; crossbeam i has round((40 - 5 i) / h) elements.
  Sizes h = 1.25 ... 0.0390625 (six, halving; 10 k elements on the finest); the finest
  gives the stored values, and the last two a Richardson estimate of each output's mesh
  error, |f_h - f_2h| / 3 (second order, which the sequence shows from h = 0.3125 on; the
  observed order of the last three meshes is stored with it).  The fine meshes are needed
  by the contact zones, not by the beams: the cylinder's pressure spans about 2.4 mm of the
  front beam, with a kink where crossbeam 4 joins it (z = 60), and the modified adaptor's
  support carries its load on the last millimetre before l_s, rising to its end.
* Adaptors.  original: both bases fully fixed.  modified: the front base pinned (x, z
  fixed, rotation free); every back-beam node with s <= l_c = 20 fully fixed (so crossbeam
  1, which lands at s = 15.81, attaches to the adaptor); a rigid unilateral support behind
  the back beam over s in (l_c, l_s] = (20, 60]: finray_jax's line through the back beam's
  base along its undeformed tangent, forward normal n = -(120, 40) / |(120, 40)| (toward
  the front beam).  Its gap is the centreline's distance to that line, g = (p - base) . n
  (no half-thickness: the line is the base's centreline, as in finray_jax._contact), and
  it pushes along n, never pulls.  Modelled with one zeroLength element per back node,
  from a fixed node at the same point, oriented along n: its deformation u . n is g
  exactly, whatever the rotation of the beam.
* Object: the 18 mm cylinder (radius R = 9), centre (-11, 60) at zero closing.  The
  finger stays put and the cylinder moves by +d in x (closing d along (-1, 0): objects
  move by -d w).  A node at the cylinder's centre, rotation and z fixed, x prescribed (sp
  constraint, load control of the prescribed displacement), is joined to every front-beam
  node within 25 mm of z = 60 by a corotTruss (A = 1) whose force depends on its current
  length L only: the radial direction of a circle is its exact normal, and the gap of the
  band (thickness t) is g = L - R - t/2.  After each solve the script checks that every
  other node of both main beams stays clear of the cylinder.
* Penalty: finray_jax's C1 law, force per unit (undeformed) length q = k ramp(-g) with
  ramp(x) = 0 (x <= 0), x^2 / (2 delta) (0 < x < delta), x - delta / 2 (x >= delta),
  lumped at the nodes with their tributary length (h; half at the ends of the supported
  range).  Each gap element's material is ElasticMultiLinear (nonlinear elastic, path
  independent) through 513 points of the quadratic part plus the exact linear asymptote;
  its largest departure from the C1 law is k delta / (8 x 512^2) per unit length (5e-7 of
  k delta).  The script recomputes every gap element's force from the deformed geometry
  with the exact law and stores the largest difference ("penalty_law_max_error_N", below
  1e-6 N).  k and delta are the finray_jax grasp's (examples/grasp_finger1*.toml):
  delta = 0.02 x 3.0 / 2 = 0.03 mm, and k = E depth / t_front = 80 N/mm^2 unless
  finray_jax's `grasp` stiffened it to keep the penetration below 0.06 mm (the modified
  adaptor: k = g.stiffness at each closing, stored in PENALTY).  Frictionless.
* Penalty study (information only; the comparison is at the same k): k x 4, x 16, x 64
  with delta / 4, / 16, / 64 (the whole penetration law scaled by 1 / m, so the outputs
  approach the rigid-contact limit linearly in 1 / k), on the h = 0.078125 mesh, and the
  limit extrapolated from the two stiffest runs.
* Shear-rigid check: the modified adaptor again with shear_k = 100 on the two finest
  meshes ("modified_shear_rigid"; see the comment in main).
* Solution: static, load control of the cylinder's prescribed displacement in steps of at
  most 0.25 mm (a step that fails is halved, down to 1/64 of it), full Newton,
  NormDispIncr 1e-10, UmfPack.  The equilibrium is elastic and frictionless, so the path
  does not matter; each closing of the modified adaptor is its own run (its own k).

Output conventions (JSON)
-------------------------
* "contact_force": (Fx, Fz) the cylinder exerts on the finger; "normal_force": the sum of
  the gap elements' force magnitudes.
* "tip": dx, dz of the tip node; "rotation" CCW positive, "rotation_about_y" = -rotation.
* "reactions": force and moment the adaptor applies to each main beam, moment about the
  beam's base point ("My_ccw", and "My_about_y" = -My_ccw).  For the modified adaptor
  "back" is the clamp's total over every fixed back node (s <= l_c), crossbeam 1's
  attachment included.
* "support_force": (Fx, Fz) the support exerts on the back beam.
* "mesh_error": the Richardson estimate of every output above (same keys).
"""

import argparse
import datetime
import json
import math
import pathlib
import platform
import sys
import time
from importlib import metadata

import numpy as np
import openseespy.opensees as ops

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import opensees_ref_a as ref_a  # noqa: E402  (sections, model setup, analysis options)

# ----------------------------------------------------------------------------- data
T_MAIN = 3.0
T_CROSS = 2.0
H_FINGER = ref_a.H_FINGER
W_BASE = ref_a.W_BASE
L_BACK = ref_a.L_BACK
Z_CROSS = ref_a.Z_CROSS
RADIUS = 9.0
CENTRE = (-11.0, 60.0)
CLAMP = 20.0  # l_c of the modified adaptor
SUPPORT = 60.0  # l_s
E_BACK = np.array([-W_BASE, H_FINGER]) / L_BACK  # back beam's unit tangent
N_SUPPORT = -np.array([H_FINGER, W_BASE]) / L_BACK  # support normal (forward)
CLOSINGS = (2.0, 4.0, 6.0)
DELTA = 0.02 * T_MAIN / 2.0
# finray_jax's penalty stiffness k (N/mm^2) of each grasp (GraspSolution.stiffness of
# grasp(finger, closing=d) on examples/grasp_finger1.toml / grasp_finger1_modified.toml;
# --penalty-from-finray recomputes them)
PENALTY = {
    ("original", 2.0): 80.0,
    ("original", 4.0): 80.0,
    ("original", 6.0): 80.0,
    ("modified", 2.0): 148.97354787789178,
    ("modified", 4.0): 264.8399562973533,
    ("modified", 6.0): 324.2284659980695,
}
N_PIECES = 512  # linear pieces of the quadratic part of the penalty law
WINDOW = 25.0  # front nodes with |z - 60| <= WINDOW get a gap element
MAX_STEP = 0.25
SHEAR_RIGID = 100.0  # Timoshenko coefficient of the shear-rigid check


def ramp(x, delta):
    x = np.asarray(x, dtype=np.float64)
    quad = np.clip(x, 0.0, delta)
    return quad * quad / (2.0 * delta) + np.maximum(x - delta, 0.0)


def penalty_points(delta):
    """Penetrations x and ramp(x) defining the piecewise-linear law (exact beyond delta)."""
    x = np.concatenate([[-1.0], np.linspace(0.0, delta, N_PIECES + 1), [delta + 10.0]])
    return x, ramp(x, delta)


# ----------------------------------------------------------------------------- model
class GraspModel:
    """Finger-1 on one adaptor, the cylinder's gap elements and the support."""

    def __init__(self, h, adaptor, k, delta, shear_k=5 / 6):
        n = round(H_FINGER / h)
        if abs(n * h - H_FINGER) > 1e-9 or abs(15.0 / h - round(15.0 / h)) > 1e-9:
            raise ValueError(f"element size {h} must divide 15")
        self.h, self.adaptor, self.k, self.delta = h, adaptor, k, delta
        ref_a.setup_model()
        self._tag = 0
        self._etag = 0
        self._mtag = 10000
        bi_front = ref_a.define_section(1, T_MAIN, shear_k)
        bi_back = ref_a.define_section(2, T_MAIN, shear_k)
        bi_cross = ref_a.define_section(3, T_CROSS, shear_k)
        ops.geomTransf("Corotational", 1)
        # front beam
        self.front_s = np.arange(n + 1) * h
        self.front = [self._node(0.0, s) for s in self.front_s]
        self.tip = self.front[-1]
        # back beam: cut at the crossbeams, l_c and l_s; the tip node is the front's
        b_cross = [z * L_BACK / H_FINGER for z in Z_CROSS]
        cuts = sorted(set([0.0, CLAMP, SUPPORT, L_BACK] + b_cross))
        hb = h * L_BACK / H_FINGER
        s_back = [0.0]
        for a, b in zip(cuts[:-1], cuts[1:]):
            m = max(1, math.ceil((b - a) / hb - 1e-9))
            s_back += [a + (b - a) * j / m for j in range(1, m + 1)]
        self.back_s = np.array(s_back)
        self.back = []
        for s in self.back_s[:-1]:
            x, z = np.array([W_BASE, 0.0]) + s * E_BACK
            self.back.append(self._node(x, z))
        self.back.append(self.tip)
        self._chain(self.front, bi_front)
        self._chain(self.back, bi_back)
        self.n_beam_elements = self._etag
        for i, z in enumerate(Z_CROSS):
            a = self.front[round(z / h)]
            jb = int(np.argmin(np.abs(self.back_s - b_cross[i])))
            assert abs(self.back_s[jb] - b_cross[i]) < 1e-9
            b = self.back[jb]
            xa, za = ops.nodeCoord(a)
            xb, zb = ops.nodeCoord(b)
            assert abs(za - z) < 1e-9 and abs(zb - z) < 1e-9
            ne = max(1, round((xb - xa) / h))
            nodes = [a] + [self._node(xa + (xb - xa) * j / ne, z) for j in range(1, ne)] + [b]
            self._chain(nodes, bi_cross)
        self.n_beam_elements = self._etag
        # supports
        if adaptor == "original":
            ops.fix(self.front[0], 1, 1, 1)
            ops.fix(self.back[0], 1, 1, 1)
            self.clamped = [self.back[0]]
        elif adaptor == "modified":
            ops.fix(self.front[0], 1, 1, 0)
            self.clamped = [nd for nd, s in zip(self.back, self.back_s) if s <= CLAMP + 1e-9]
            for nd in self.clamped:
                ops.fix(nd, 1, 1, 1)
        else:
            raise ValueError(adaptor)
        # the cylinder
        self.centre = self._node(*CENTRE)
        ops.fix(self.centre, 0, 1, 1)
        self.gaps = []  # (element, beam node, tributary length)
        for j, (nd, s) in enumerate(zip(self.front, self.front_s)):
            if 0 < j < n and abs(s - CENTRE[1]) <= WINDOW:
                self.gaps.append((self._gap(nd, h), nd, h))
        # the support
        self.support = []
        if adaptor == "modified":
            for j, (nd, s) in enumerate(zip(self.back, self.back_s)):
                if CLAMP + 1e-9 < s <= SUPPORT + 1e-9:
                    lo = max(self.back_s[j - 1], CLAMP)
                    hi = min(self.back_s[j + 1], SUPPORT)
                    trib = 0.5 * (s - lo) + 0.5 * max(hi - s, 0.0)
                    self.support.append((self._support(nd, trib), nd, trib))
        self.n_elements = self._etag

    def _node(self, x, z):
        self._tag += 1
        ops.node(self._tag, float(x), float(z))
        return self._tag

    def _chain(self, nodes, bi):
        for a, b in zip(nodes[:-1], nodes[1:]):
            self._etag += 1
            ops.element("forceBeamColumn", self._etag, a, b, 1, bi)

    def _material(self, strain, force):
        """Nonlinear elastic law force(strain) through the given points (increasing
        strain), extrapolated linearly beyond them."""
        self._mtag += 1
        order = np.argsort(strain)
        ops.uniaxialMaterial(
            "ElasticMultiLinear",
            self._mtag,
            "-strain",
            *[float(v) for v in np.asarray(strain)[order]],
            "-stress",
            *[float(v) for v in np.asarray(force)[order]],
        )
        return self._mtag

    def _gap(self, nd, trib):
        """corotTruss centre -> nd, axial force -k trib ramp(R + t/2 - L) (compression)."""
        x0, z0 = ops.nodeCoord(nd)
        length0 = math.hypot(x0 - CENTRE[0], z0 - CENTRE[1])
        pen, r = penalty_points(self.delta)
        strain = (RADIUS + T_MAIN / 2 - pen) / length0 - 1.0
        mat = self._material(strain, -self.k * trib * r)
        self._etag += 1
        ops.element("corotTruss", self._etag, self.centre, nd, 1.0, mat)
        return self._etag

    def _support(self, nd, trib):
        """zeroLength from a fixed node at nd's place, along the support normal: its
        deformation is the gap g = u . n, force -k trib ramp(-g) (compression)."""
        x0, z0 = ops.nodeCoord(nd)
        fixed = self._node(x0, z0)
        ops.fix(fixed, 1, 1, 1)
        pen, r = penalty_points(self.delta)
        mat = self._material(-pen, -self.k * trib * r)
        self._etag += 1
        nx, nz = N_SUPPORT
        ops.element(
            "zeroLength", self._etag, fixed, nd, "-mat", mat, "-dir", 1,
            "-orient", nx, nz, 0.0, -nz, nx, 0.0,
        )  # fmt: skip
        return self._etag

    # ---- results
    def _position(self, nd):
        return np.array(ops.nodeCoord(nd)) + np.array(ops.nodeDisp(nd)[:2])

    def results(self):
        ops.reactions()
        c = self._position(self.centre)
        force = np.zeros(2)
        normal = 0.0
        law_err = 0.0
        for e, nd, trib in self.gaps:
            f = -np.array(ops.eleForce(e)[3:5])  # force of the element on the beam node
            force += f
            normal += float(np.linalg.norm(f))
            p = self._position(nd)
            dist = float(np.linalg.norm(p - c))
            exact = self.k * trib * float(ramp(RADIUS + T_MAIN / 2 - dist, self.delta))
            law_err = max(law_err, abs(float(np.linalg.norm(f)) - exact))
            if exact > 0:  # the force is radial
                u = (p - c) / dist
                law_err = max(law_err, float(np.linalg.norm(f - exact * u)))
        support = np.zeros(2)
        for e, nd, trib in self.support:
            f = -np.array(ops.eleForce(e)[3:5])
            support += f
            gap = float((self._position(nd) - ops.nodeCoord(nd)) @ N_SUPPORT)
            exact = self.k * trib * float(ramp(-gap, self.delta))
            law_err = max(law_err, float(np.linalg.norm(f - exact * N_SUPPORT)))
        # every node without a gap element stays clear of the cylinder
        touching = {nd for _, nd, _ in self.gaps}
        clear = min(
            float(np.linalg.norm(self._position(nd) - c)) - RADIUS - T_MAIN / 2
            for nd in self.front[1:] + self.back[1:]
            if nd not in touching
        )
        out = {
            "contact_force": {"Fx": float(force[0]), "Fz": float(force[1])},
            "normal_force": normal,
        }
        rot = ops.nodeDisp(self.tip, 3)
        out["tip"] = {
            "dx": ops.nodeDisp(self.tip, 1),
            "dz": ops.nodeDisp(self.tip, 2),
            "rotation": rot,
            "rotation_about_y": -rot,
        }
        out["reactions"] = {}
        for name, nodes, base in (
            ("front", [self.front[0]], (0.0, 0.0)),
            ("back", self.clamped, (W_BASE, 0.0)),
        ):
            fx = fz = m = 0.0
            for nd in nodes:
                r = ops.nodeReaction(nd)
                x, z = ops.nodeCoord(nd)
                fx += r[0]
                fz += r[1]
                m += r[2] + (x - base[0]) * r[1] - (z - base[1]) * r[0]
            out["reactions"][name] = {"Fx": fx, "Fz": fz, "My_ccw": m, "My_about_y": -m}
        out["support_force"] = {"Fx": float(support[0]), "Fz": float(support[1])}
        # balance of everything on the finger
        rf, rb = out["reactions"]["front"], out["reactions"]["back"]
        out["equilibrium_residual"] = {
            "Fx": float(force[0] + support[0] + rf["Fx"] + rb["Fx"]),
            "Fz": float(force[1] + support[1] + rf["Fz"] + rb["Fz"]),
        }
        out["penalty_law_max_error_N"] = law_err
        out["clearance_of_other_nodes_mm"] = clear
        out["max_penetration_nodes_mm"] = max(
            [
                RADIUS + T_MAIN / 2 - float(np.linalg.norm(self._position(nd) - c))
                for _, nd, _ in self.gaps
            ]
        )
        return out


# ----------------------------------------------------------------------------- solution
def static_analysis(step, tol=1e-10, max_iter=60):
    """opensees_ref_a's analysis, with the Transformation handler (the cylinder's
    prescribed displacement is a non-homogeneous constraint, which Plain ignores)."""
    ops.wipeAnalysis()
    ops.system("UmfPack")
    ops.numberer("RCM")
    ops.constraints("Transformation")
    ops.test("NormDispIncr", tol, max_iter, 0)
    ops.algorithm("Newton")
    ops.integrator("LoadControl", step)
    ops.analysis("Static")


def close(model, targets):
    """Move the cylinder by +d in x (load control of its prescribed x) through the sorted
    closings `targets`; returns {d: results} and the number of steps taken."""
    ops.timeSeries("Linear", 1)
    ops.pattern("Plain", 1, 1)
    ops.sp(model.centre, 1, 1.0)
    out = {}
    steps = 0

    def advance(du, depth=0):
        nonlocal steps
        static_analysis(du)
        if ops.analyze(1) == 0:
            steps += 1
            return
        if depth >= 6:
            raise RuntimeError(f"no convergence at closing {ops.getTime():.6f} mm")
        for _ in range(2):
            advance(du / 2, depth + 1)

    for d in targets:
        rest = d - ops.getTime()
        m = max(1, math.ceil(rest / MAX_STEP - 1e-9))
        for _ in range(m):
            advance(rest / m)
        if abs(ops.getTime() - d) > 1e-9 or abs(ops.nodeDisp(model.centre, 1) - d) > 1e-9:
            raise RuntimeError(f"closing {ops.nodeDisp(model.centre, 1)} != {d}")
        out[d] = model.results()
    return out, steps


def solve_adaptor(h, adaptor, scale=1.0, shear_k=5 / 6):
    """Results of one adaptor at every closing on one mesh.  scale multiplies k and divides
    delta (penalty study); shear_k: the sections' Timoshenko coefficient."""
    res = {}
    t0 = time.time()
    if adaptor == "original":
        k = {PENALTY[("original", d)] for d in CLOSINGS}
        assert len(k) == 1
        model = GraspModel(h, adaptor, k.pop() * scale, DELTA / scale, shear_k)
        out, steps = close(model, CLOSINGS)
        res.update(out)
    else:
        steps = 0
        for d in CLOSINGS:
            model = GraspModel(h, adaptor, PENALTY[(adaptor, d)] * scale, DELTA / scale, shear_k)
            out, st = close(model, [d])
            res.update(out)
            steps += st
    info = {
        "h": h,
        "n_beam_elements": model.n_beam_elements,
        "n_gap_elements": len(model.gaps),
        "n_support_elements": len(model.support),
        "load_steps": steps,
        "seconds": time.time() - t0,
    }
    return res, info


# ----------------------------------------------------------------------------- outputs
def flat(res):
    """The compared outputs of one result as {name: value}."""
    r = res["reactions"]
    out = {
        "contact_force.Fx": res["contact_force"]["Fx"],
        "contact_force.Fz": res["contact_force"]["Fz"],
        "normal_force": res["normal_force"],
        "tip.dx": res["tip"]["dx"],
        "tip.dz": res["tip"]["dz"],
        "tip.rotation": res["tip"]["rotation"],
        "support_force.Fx": res["support_force"]["Fx"],
        "support_force.Fz": res["support_force"]["Fz"],
    }
    for b in ("front", "back"):
        for q in ("Fx", "Fz", "My_ccw"):
            out[f"reactions.{b}.{q}"] = r[b][q]
    return out


def unflat(values):
    out = {}
    for name, v in values.items():
        node = out
        *path, last = name.split(".")
        for p in path:
            node = node.setdefault(p, {})
        node[last] = v
    return out


def richardson(seq):
    """seq: flat outputs on meshes h, h/2, ... (coarse to fine).  Per output: the error
    estimate of the finest, |f_h - f_2h| / 3, the observed order from the last three
    meshes, and the extrapolated value."""
    err, order, extra = {}, {}, {}
    for key in seq[-1]:
        f = [s[key] for s in seq]
        d1 = f[-1] - f[-2]
        err[key] = abs(d1) / 3.0
        extra[key] = f[-1] + d1 / 3.0
        if len(f) >= 3 and d1 != 0 and f[-2] != f[-3]:
            order[key] = math.log2(abs(f[-2] - f[-3]) / abs(d1))
        else:
            order[key] = None
    return err, order, extra


def penalty_from_finray():
    """k of finray_jax's grasps of the two example files (needs finray_jax)."""
    import finray_jax as fr
    from finray_jax.io import load_finger

    root = pathlib.Path(__file__).resolve().parents[2] / "examples"
    out = {}
    for adaptor, name in (
        ("original", "grasp_finger1.toml"),
        ("modified", "grasp_finger1_modified.toml"),
    ):
        finger, _ = load_finger(root / name)
        for d in CLOSINGS:
            out[(adaptor, d)] = float(fr.grasp(finger, closing=d).stiffness)
    return out


# ----------------------------------------------------------------------------- driver
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="tests/data/grasp_opensees.json")
    ap.add_argument("--sizes", default="1.25,0.625,0.3125,0.15625,0.078125,0.0390625")
    ap.add_argument("--quick", action="store_true", help="only the two coarsest meshes")
    ap.add_argument("--penalty-h", type=float, default=0.078125)
    ap.add_argument("--penalty-scales", default="4,16,64")
    ap.add_argument("--penalty-from-finray", action="store_true")
    args = ap.parse_args(argv)
    sizes = sorted((float(v) for v in args.sizes.split(",")), reverse=True)
    if args.quick:
        sizes = sizes[:2]
    if args.penalty_from_finray:
        PENALTY.update(penalty_from_finray())
        print("penalty from finray_jax:", PENALTY, flush=True)
    t_start = time.time()
    data = {
        "description": "Finger-1 grasping an 18 mm cylinder (original and modified adaptor), "
        "OpenSees 2-D corotational forceBeamColumn + gap elements; see script docstring",
        "generator": "tests/reference/opensees_grasp.py",
        "date": datetime.date.today().isoformat(),
        "versions": {
            "openseespy": metadata.version("openseespy"),
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "units": "mm, N, MPa",
        "conventions": {
            "plane": "OpenSees X = x, OpenSees Y = z",
            "closing": "the cylinder moves by +d in x (the finger closes along (-1, 0))",
            "rotation": "CCW positive in the (x, z) plane viewed with x right, z up; "
            "rotation_about_y = -rotation",
            "contact_force": "force of the cylinder on the finger",
            "support_force": "force of the support on the back beam",
            "reactions": "force/moment the adaptor applies to each main beam, moment about "
            "the beam's base point (front (0, 0), back (40, 0)); modified 'back' = the "
            "clamp's total over s <= l_c",
        },
        "model": {
            "E": ref_a.E_MOD,
            "nu": ref_a.NU,
            "depth": ref_a.DEPTH,
            "t_main": T_MAIN,
            "t_cross": T_CROSS,
            "shear_k": 5 / 6,
            "cylinder": {"radius": RADIUS, "centre_at_zero_closing": CENTRE},
            "clamp_length": CLAMP,
            "support_length": SUPPORT,
            "support_normal": N_SUPPORT.tolist(),
            "penalty_law": "q = k ramp(-g), ramp C1 with smoothing delta; ElasticMultiLinear "
            f"with {N_PIECES} pieces on [0, delta] and the exact asymptote",
            "delta": DELTA,
            "penalty_k": {f"{a}_{d:g}": k for (a, d), k in PENALTY.items()},
            "element": "forceBeamColumn, Lobatto 3 points, geomTransf Corotational; "
            "corotTruss (A = 1) gap elements; zeroLength support elements",
            "solver": "Newton, NormDispIncr 1e-10, UmfPack, load control of the prescribed "
            f"cylinder displacement, steps <= {MAX_STEP} mm",
        },
        "closings": list(CLOSINGS),
        "mesh_sizes": sizes,
        "element_size": sizes[-1],
        "quick": args.quick,
    }
    for adaptor in ("original", "modified"):
        per_h, infos = [], []
        for h in sizes:
            res, info = solve_adaptor(h, adaptor)
            per_h.append(res)
            infos.append(info)
            for d in CLOSINGS:
                r = res[d]
                print(
                    f"{adaptor} h={h} d={d}: F=({r['contact_force']['Fx']:.6f},"
                    f" {r['contact_force']['Fz']:.6f}) N={r['normal_force']:.6f}"
                    f" tip=({r['tip']['dx']:.6f}, {r['tip']['dz']:.6f})"
                    f" S=({r['support_force']['Fx']:.6f}, {r['support_force']['Fz']:.6f})"
                    f" [{info['seconds']:.1f}s]",
                    flush=True,
                )
        block = {"meshes": infos}
        for d in CLOSINGS:
            seq = [flat(res[d]) for res in per_h]
            err, order, extra = richardson(seq)
            case = per_h[-1][d]
            case["k"] = PENALTY[(adaptor, d)]
            case["delta"] = DELTA
            case["element_size"] = sizes[-1]
            case["mesh_error"] = unflat(err)
            case["observed_order"] = unflat(order)
            case["richardson_extrapolated"] = unflat(extra)
            case["convergence"] = [{"h": h, **s} for h, s in zip(sizes, seq)]
            block[f"{d:g}"] = case
        data[adaptor] = block

    if not args.quick:
        study = {
            "h": args.penalty_h,
            "note": "k x m with delta / m; the comparison is at m = 1. rigid_limit: "
            "Richardson in 1/k from the two stiffest runs",
        }
        scales = [1.0] + [float(v) for v in args.penalty_scales.split(",")]
        for adaptor in ("original", "modified"):
            runs = {}
            for m in scales:
                res, info = solve_adaptor(args.penalty_h, adaptor, m)
                runs[m] = res
                print(f"penalty {adaptor} x{m:g}: {info['seconds']:.1f}s", flush=True)
            for d in CLOSINGS:
                seq = {f"x{m:g}": flat(runs[m][d]) for m in scales}
                a, b = flat(runs[scales[-2]][d]), flat(runs[scales[-1]][d])
                r = scales[-1] / scales[-2]
                limit = {key: b[key] + (b[key] - a[key]) / (r - 1.0) for key in b}
                study[f"{adaptor}_{d:g}"] = {
                    "runs": seq,
                    "rigid_limit": limit,
                    "max_penetration_nodes_mm": {
                        f"x{m:g}": runs[m][d]["max_penetration_nodes_mm"] for m in scales
                    },
                }
        data["penalty_study"] = study
        # Nearly shear-rigid sections (shear_k = 100): the modified adaptor's grasps
        # shear the beams by up to 6 % where they press on the cylinder and on the
        # support's end, where a corotational Timoshenko element (shear = angle between
        # chord and section, forces resolved on the chord) and a geometrically exact rod
        # (shear = tangent component along the section's normal) differ at first order in
        # that strain.  Without shear strain they describe the same rod.
        shear = {"shear_k": SHEAR_RIGID, "mesh_sizes": sizes[-2:]}
        runs = [solve_adaptor(h, "modified", shear_k=SHEAR_RIGID)[0] for h in sizes[-2:]]
        for d in CLOSINGS:
            seq = [flat(r[d]) for r in runs]
            err, _, _ = richardson(seq)
            shear[f"{d:g}"] = {"values": unflat(seq[-1]), "mesh_error": unflat(err)}
            print(f"shear-rigid modified d={d}: {seq[-1]['contact_force.Fx']:.6f}", flush=True)
        data["modified_shear_rigid"] = shear
    data["total_seconds"] = time.time() - t_start
    with open(args.out, "w") as f:
        json.dump(data, f, indent=1)
    print("wrote", args.out, f"({time.time() - t_start:.0f}s)")


if __name__ == "__main__":
    main()
