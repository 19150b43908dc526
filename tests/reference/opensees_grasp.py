"""Independent reference for grasping: Finger-1 closing on a rigid cylinder, with OpenSees.

Run:  python tests/reference/opensees_grasp.py --penalty-from-finray \
          --out tests/data/grasp_opensees.json
      (--quick: only the two coarsest meshes and no penalty study, for a reproducibility
      test; --penalty-from-finray: run finray_jax's grasps for the penalty stiffnesses
      instead of taking the PENALTY table, and store what they report; --cases: a subset)

Cases: "original" (examples/grasp_finger1.toml) and "modified"
(grasp_finger1_modified.toml) at finray_jax's default penetration limit
(contact.max_penetration = 0.02 of the beams' thickness), and "modified_tight", the
modified adaptor with contact.max_penetration = 0.002 (the support's limit follows it:
max_support_penetration is None), each at closings 2, 4 and 6 mm.

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
* Mesh: elements of size h on the front beam, and h FRONT_REFINE = h / 8 over
  FRONT_ZONE = 57.5 <= z <= 62.5, where the cylinder presses (nodes at every 15 mm and at
  the zone's ends); the back beam is cut at the crossbeams, at l_c = 20 and at l_s = 60,
  each piece split into elements no longer than h L_back / 120, and for the modified
  adaptor no longer than EDGE_REFINE = 1/32 of that within EDGE_ZONE = 0.5 mm of l_s;
  crossbeam i has round((40 - 5 i) / h) elements.  Sizes h = 1.25 ... 0.0390625 (six,
  halving; 11 k elements on the finest); the finest gives the stored values, and the
  last two a Richardson estimate of each output's mesh error, |f_h - f_2h| / 3 (second
  order; the observed order of the last three meshes is stored with it).  The fine meshes
  are needed by the contact zones, not by the beams.  The cylinder's pressure spans 1 to
  2.5 mm of the front beam ("front_contact_z_mm"), with a kink where crossbeam 4 joins it
  (z = 60): without the front zone the tight case's tip displacement and clamp moment
  converge as slowly as h^0.2.  The support's stiff penalty carries nearly all its
  load on the back beam's last 0.02 to 0.25 mm before l_s (the shorter, the stiffer k_s):
  the support's end is a corner the beam bends over, sheared (a concentrated force kinks a
  Timoshenko beam's centreline by F / (k G A)), so the penetration there rises at a slope
  of 0.2 to 0.4; without the back zone the modified outputs change irregularly by up to
  1 % between the finest meshes.
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
  lumped at the nodes with their tributary length (half of each adjacent element, within
  the supported range).  The cylinder has its (k, delta), the support its own (k_s,
  delta_s), as in finray_jax (Contact.stiffness / support_stiffness):
    delta = max_penetration x t_front / 2, delta_s = max_support_penetration x t_back / 2
  (0.03 mm for original and modified, 0.003 mm for modified_tight), and (k, k_s) =
  (g.stiffness, g.support_stiffness) of finray_jax's default grasp(finger, closing=d) of
  the case (stored in PENALTY): k starts at E depth / t_front = 80 N/mm^2, k_s at k, and
  `grasp` stiffens each until the penetration it reads at its solution points stays below
  2 delta (delta_s); those grasps' reports are stored ("finray_grasp").  The original
  adaptor has no support and keeps k = 80.  (At the tight case's k_s the resolved support
  penetration here, "max_support_penetration_nodes_mm", is 0.0050, 0.0066 and 0.026 mm at
  2, 4, 6 mm against its 0.006 mm limit, where finray_jax's 16-step grasp read 0, 7e-5 and
  0.0029 mm: its support contact is shorter than an integration step.) Each gap element's
  material is ElasticMultiLinear (nonlinear elastic, path independent) through n + 1
  points of the quadratic part plus the exact linear asymptote; its largest departure from
  the C1 law is k delta / (8 n^2) per unit length, and n (a power of 2, at least 512, up
  to 16384 for the tight support) keeps that below 1e-6 N/mm.  The script recomputes every
  gap element's force from the deformed geometry with the exact law and stores the largest
  difference ("penalty_law_max_error_N", below 1e-6 N).  Frictionless.
* Penalty study (information only; the comparison is at the same k and k_s), original and
  modified: k and k_s x 4, x 16, x 64 with delta and delta_s / 4, / 16, / 64 (the whole
  penetration law scaled by 1 / m, so the outputs approach the rigid-contact limit
  linearly in 1 / k), on the h = 0.078125 mesh, and the limit extrapolated from the two
  stiffest runs.
* Shear-rigid check: the modified case again with shear_k = 100 on the two finest
  meshes ("modified_shear_rigid"; see the comment in main).
* Solution: static, load control of the cylinder's prescribed displacement in steps of at
  most 0.25 mm (a step that fails is halved, down to 1/64 of it; the tight case halves a
  few), full Newton, NormDispIncr 1e-10, UmfPack.  The equilibrium is elastic and
  frictionless, so the path does not matter; each closing of the modified cases is its
  own run (its own k and k_s).

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
* "max_penetration_nodes_mm", "max_support_penetration_nodes_mm": the largest penetration
  of a node into the cylinder and into the support; "front_contact_z_mm": the undeformed
  z range of the front-beam nodes the cylinder presses.
* "k", "k_s", "delta", "delta_s": the case's penalty law (also "model"/"penalty").
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
# The cases: adaptor, example file and contact.max_penetration (the fraction of the main
# beams' thickness 3.0 both penetration limits take: max_support_penetration is None)
CASES = {
    "original": ("original", "grasp_finger1.toml", 0.02),
    "modified": ("modified", "grasp_finger1_modified.toml", 0.02),
    "modified_tight": ("modified", "grasp_finger1_modified.toml", 0.002),
}
# finray_jax's penalty stiffnesses (N/mm^2) of each grasp: (k, k_s) = (GraspSolution.
# stiffness, .support_stiffness) of grasp(finger, closing=d) on the case's example file
# with its max_penetration (--penalty-from-finray recomputes them).  The original adaptor
# has no support (its k_s is unused).
PENALTY = {
    ("original", 2.0): (80.0, 80.0),
    ("original", 4.0): (80.0, 80.0),
    ("original", 6.0): (80.0, 80.0),
    ("modified", 2.0): (148.9718617640604, 3387.453740030261),
    ("modified", 4.0): (336.62282205889494, 7323.358407821429),
    ("modified", 6.0): (417.83698552602453, 10185.661171883708),
    ("modified_tight", 2.0): (4477.100721592361, 327680.0),
    ("modified_tight", 4.0): (10469.225542268921, 723659.5306994147),
    ("modified_tight", 6.0): (17046.967311726745, 1016456.7660008746),
}


def smoothings(case):
    """(delta, delta_s) of a case: max_penetration x thickness / 2 (front; back)."""
    frac = CASES[case][2]
    return frac * T_MAIN / 2.0, frac * T_MAIN / 2.0


N_PIECES = 512  # the fewest linear pieces of the quadratic part of the penalty law
LAW_ERROR = 1e-6  # N/mm: the largest departure of the piecewise-linear law from ramp
WINDOW = 25.0  # front nodes with |z - 60| <= WINDOW get a gap element
EDGE_ZONE = 0.5  # mm each side of l_s where the back beam's elements are refined ...
EDGE_REFINE = 1 / 32  # ... to this fraction of their size elsewhere (modified adaptor)
FRONT_ZONE = (57.5, 62.5)  # the front beam's range (z) whose elements are refined ...
FRONT_REFINE = 1 / 8  # ... to this fraction of h (the cylinder's contact)
MAX_STEP = 0.25
SHEAR_RIGID = 100.0  # Timoshenko coefficient of the shear-rigid check


def ramp(x, delta):
    x = np.asarray(x, dtype=np.float64)
    quad = np.clip(x, 0.0, delta)
    return quad * quad / (2.0 * delta) + np.maximum(x - delta, 0.0)


def n_pieces(k, delta):
    """Linear pieces of the quadratic part: at least N_PIECES, a power of 2, enough that
    k times the interpolation error delta / (8 n^2) stays below LAW_ERROR."""
    need = math.sqrt(k * delta / (8.0 * LAW_ERROR))
    return max(N_PIECES, 2 ** math.ceil(math.log2(need)))


def penalty_points(k, delta):
    """Penetrations x and ramp(x) defining the piecewise-linear law of stiffness k (exact
    beyond delta)."""
    n = n_pieces(k, delta)
    x = np.concatenate([[-1.0], np.linspace(0.0, delta, n + 1), [delta + 10.0]])
    return x, ramp(x, delta)


# ----------------------------------------------------------------------------- model
class GraspModel:
    """Finger-1 on one adaptor, the cylinder's gap elements and the support."""

    def __init__(self, h, adaptor, k, delta, k_s, delta_s, shear_k=5 / 6):
        n = round(H_FINGER / h)
        if abs(n * h - H_FINGER) > 1e-9 or abs(15.0 / h - round(15.0 / h)) > 1e-9:
            raise ValueError(f"element size {h} must divide 15")
        self.h, self.adaptor, self.k, self.delta = h, adaptor, k, delta
        self.k_s, self.delta_s = k_s, delta_s
        ref_a.setup_model()
        self._tag = 0
        self._etag = 0
        self._mtag = 10000
        bi_front = ref_a.define_section(1, T_MAIN, shear_k)
        bi_back = ref_a.define_section(2, T_MAIN, shear_k)
        bi_cross = ref_a.define_section(3, T_CROSS, shear_k)
        ops.geomTransf("Corotational", 1)
        # front beam
        cuts = sorted(set([0.0, H_FINGER, *FRONT_ZONE] + list(Z_CROSS)))
        s_front = [0.0]
        for a, b in zip(cuts[:-1], cuts[1:]):
            fine = FRONT_ZONE[0] <= 0.5 * (a + b) <= FRONT_ZONE[1]
            m = max(1, round((b - a) / (h * (FRONT_REFINE if fine else 1.0))))
            s_front += [a + (b - a) * j / m for j in range(1, m + 1)]
        self.front_s = np.array(s_front)
        self.front = [self._node(0.0, s) for s in self.front_s]
        self.tip = self.front[-1]
        # back beam: cut at the crossbeams, l_c and l_s; the tip node is the front's
        b_cross = [z * L_BACK / H_FINGER for z in Z_CROSS]
        cuts = [0.0, CLAMP, SUPPORT, L_BACK] + b_cross
        if adaptor == "modified":
            cuts += [SUPPORT - EDGE_ZONE, SUPPORT + EDGE_ZONE]
        cuts = sorted(set(cuts))
        hb = h * L_BACK / H_FINGER
        s_back = [0.0]
        for a, b in zip(cuts[:-1], cuts[1:]):
            edge = adaptor == "modified" and abs(0.5 * (a + b) - SUPPORT) < EDGE_ZONE
            m = max(1, math.ceil((b - a) / (hb * (EDGE_REFINE if edge else 1.0)) - 1e-9))
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
            a = self.front[int(np.argmin(np.abs(self.front_s - z)))]
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
        fs = self.front_s
        self.gap_s = []  # undeformed z of each gap element's node
        for j, (nd, s) in enumerate(zip(self.front, fs)):
            if 0 < j < len(fs) - 1 and abs(s - CENTRE[1]) <= WINDOW:
                trib = 0.5 * (fs[j + 1] - fs[j - 1])
                self.gaps.append((self._gap(nd, trib), nd, trib))
                self.gap_s.append(float(s))
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
        pen, r = penalty_points(self.k, self.delta)
        strain = (RADIUS + T_MAIN / 2 - pen) / length0 - 1.0
        mat = self._material(strain, -self.k * trib * r)
        self._etag += 1
        ops.element("corotTruss", self._etag, self.centre, nd, 1.0, mat)
        return self._etag

    def _support(self, nd, trib):
        """zeroLength from a fixed node at nd's place, along the support normal: its
        deformation is the gap g = u . n, force -k_s trib ramp(-g) with the support's
        smoothing delta_s (compression)."""
        x0, z0 = ops.nodeCoord(nd)
        fixed = self._node(x0, z0)
        ops.fix(fixed, 1, 1, 1)
        pen, r = penalty_points(self.k_s, self.delta_s)
        mat = self._material(-pen, -self.k_s * trib * r)
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
        support_pen = 0.0
        for e, nd, trib in self.support:
            f = -np.array(ops.eleForce(e)[3:5])
            support += f
            gap = float((self._position(nd) - ops.nodeCoord(nd)) @ N_SUPPORT)
            support_pen = max(support_pen, -gap)
            exact = self.k_s * trib * float(ramp(-gap, self.delta_s))
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
        out["max_support_penetration_nodes_mm"] = support_pen
        pressed = [
            s for (e, _, _), s in zip(self.gaps, self.gap_s) if ops.eleForce(e)[3:5] != [0, 0]
        ]
        out["front_contact_z_mm"] = [min(pressed), max(pressed)] if pressed else None
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


def solve_case(h, case, scale=1.0, shear_k=5 / 6):
    """Results of one case at every closing on one mesh.  scale multiplies k and k_s and
    divides delta and delta_s (penalty study); shear_k: the sections' Timoshenko
    coefficient.  Closings with the same penalty share one run (the original adaptor's);
    every other closing is its own run from the open finger."""
    adaptor = CASES[case][0]
    delta, delta_s = smoothings(case)
    res = {}
    t0 = time.time()
    runs = {}
    for d in CLOSINGS:
        runs.setdefault(PENALTY[(case, d)], []).append(d)
    steps = 0
    for (k, k_s), targets in runs.items():
        model = GraspModel(
            h, adaptor, k * scale, delta / scale, k_s * scale, delta_s / scale, shear_k
        )
        out, st = close(model, targets)
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
    """(k, k_s) of finray_jax's default grasp of every case and closing (needs finray_jax),
    and what that grasp reports: converged, and its penetrations (mm) into the cylinder and
    the support with their limits.  Raises if a grasp failed or exceeds a limit."""
    import equinox as eqx
    import jax.numpy as jnp

    import finray_jax as fr
    from finray_jax.io import load_finger

    root = pathlib.Path(__file__).resolve().parents[2] / "examples"
    penalty, checks = {}, {}
    for case, (_, name, frac) in CASES.items():
        finger, _ = load_finger(root / name)
        finger = eqx.tree_at(lambda f: f.contact.max_penetration, finger, jnp.asarray(frac))
        for d in CLOSINGS:
            g = fr.grasp(finger, closing=d)
            c = g.contact
            limit = frac * T_MAIN  # both limits: the same fraction, both beams 3.0 thick
            check = {
                "converged": g.converged,
                "max_penetration_mm": float(c.max_penetration),
                "support_penetration_mm": float(c.support_penetration),
                "limit_mm": limit,
                "warnings": g.penetration_warnings(),
            }
            ok = check["converged"] and not check["warnings"]
            ok = ok and max(check["max_penetration_mm"], check["support_penetration_mm"]) <= limit
            if not ok:
                raise RuntimeError(f"finray_jax's grasp of {case} at {d} mm: {check}")
            penalty[(case, d)] = (float(g.stiffness), float(g.support_stiffness))
            checks[f"{case}_{d:g}"] = check
    return penalty, checks


# ----------------------------------------------------------------------------- driver
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="tests/data/grasp_opensees.json")
    ap.add_argument("--sizes", default="1.25,0.625,0.3125,0.15625,0.078125,0.0390625")
    ap.add_argument("--quick", action="store_true", help="only the two coarsest meshes")
    ap.add_argument("--penalty-h", type=float, default=0.078125)
    ap.add_argument("--penalty-scales", default="4,16,64")
    ap.add_argument("--penalty-from-finray", action="store_true")
    ap.add_argument("--cases", default=",".join(CASES))
    args = ap.parse_args(argv)
    sizes = sorted((float(v) for v in args.sizes.split(",")), reverse=True)
    cases = args.cases.split(",")
    if args.quick:
        sizes = sizes[:2]
    finray_checks = None
    if args.penalty_from_finray:
        new, finray_checks = penalty_from_finray()
        for key, value in new.items():
            if value != PENALTY[key]:
                print(f"PENALTY{key}: finray_jax gives {value}, the table {PENALTY[key]}")
        PENALTY.update(new)
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
            "with n pieces on [0, delta] (n: a power of 2, at least "
            f"{N_PIECES}, with k delta / (8 n^2) <= {LAW_ERROR} N/mm) and the exact asymptote",
            "cases": {
                case: {"adaptor": adaptor, "example": name, "max_penetration": frac}
                for case, (adaptor, name, frac) in CASES.items()
                if case in cases
            },
            "penalty": {
                f"{c}_{d:g}": dict(zip(("k", "k_s", "delta", "delta_s"), k + smoothings(c)))
                for (c, d), k in PENALTY.items()
                if c in cases
            },
            "penalty_source": "finray_jax grasp, recomputed by this run"
            if finray_checks
            else "the script's PENALTY table (finray_jax's grasp values)",
            "refined": {
                "front_z": list(FRONT_ZONE),
                "front_fraction": FRONT_REFINE,
                "back_around_support_end_mm": EDGE_ZONE,
                "back_fraction": EDGE_REFINE,
            },
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
    if finray_checks:
        data["finray_grasp"] = finray_checks
    for name in cases:
        per_h, infos = [], []
        for h in sizes:
            res, info = solve_case(h, name)
            per_h.append(res)
            infos.append(info)
            for d in CLOSINGS:
                r = res[d]
                print(
                    f"{name} h={h} d={d}: F=({r['contact_force']['Fx']:.6f},"
                    f" {r['contact_force']['Fz']:.6f}) N={r['normal_force']:.6f}"
                    f" tip=({r['tip']['dx']:.6f}, {r['tip']['dz']:.6f})"
                    f" S=({r['support_force']['Fx']:.6f}, {r['support_force']['Fz']:.6f})"
                    f" [{info['seconds']:.1f}s, {info['load_steps']} steps]",
                    flush=True,
                )
        block = {"max_penetration": CASES[name][2], "meshes": infos}
        for d in CLOSINGS:
            seq = [flat(res[d]) for res in per_h]
            err, order, extra = richardson(seq)
            case = per_h[-1][d]
            case["k"], case["k_s"] = PENALTY[(name, d)]
            case["delta"], case["delta_s"] = smoothings(name)
            case["element_size"] = sizes[-1]
            case["mesh_error"] = unflat(err)
            case["observed_order"] = unflat(order)
            case["richardson_extrapolated"] = unflat(extra)
            case["convergence"] = [{"h": h, **s} for h, s in zip(sizes, seq)]
            block[f"{d:g}"] = case
        data[name] = block

    if not args.quick and cases == list(CASES):
        study = {
            "h": args.penalty_h,
            "note": "k and k_s x m with delta and delta_s / m; the comparison is at m = 1. "
            "rigid_limit: "
            "Richardson in 1/k from the two stiffest runs",
        }
        scales = [1.0] + [float(v) for v in args.penalty_scales.split(",")]
        for adaptor in ("original", "modified"):
            runs = {}
            for m in scales:
                res, info = solve_case(args.penalty_h, adaptor, m)
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
                    "max_support_penetration_nodes_mm": {
                        f"x{m:g}": runs[m][d]["max_support_penetration_nodes_mm"] for m in scales
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
        runs = [solve_case(h, "modified", shear_k=SHEAR_RIGID)[0] for h in sizes[-2:]]
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
