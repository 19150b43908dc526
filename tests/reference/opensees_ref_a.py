"""Independent reference solution of the fin-ray finger "ref-A" with OpenSees.

Run:  python tests/reference/opensees_ref_a.py --out tests/data/ref_a_opensees.json

Model (see reference/ref_finger_A.md; units mm, N, MPa)
-------------------------------------------------------
* 2-D OpenSees model (ndm=2, ndf=3).  The spec's x-z plane is OpenSees' X-Y plane:
  OpenSees X = spec x, OpenSees Y = spec z.  Degree of freedom 3 is the in-plane rotation,
  counter-clockwise positive in (X, Y) = (x, z) viewed with x to the right and z up.
* Front beam (0,0)->(0,120); back beam (40,0)->(0,120) (length 126.4911).  The tip is ONE
  node shared by both beams (rigid joint).  Seven horizontal crossbeams at z_i = 15 i share
  the nodes of the main beams at (0, z_i) and (40 (1 - z_i/120), z_i) (rigid joints,
  centreline to centreline, no offsets).  Both bases are fully fixed.
* Sections: rectangles, depth 20, in-plane thickness t (front/back 1.5, crossbeams 1.0);
  A = 20 t, I = 20 t^3 / 12.  E = 12, nu = 0.45, G = E / (2 (1 + nu)).
* Elements: forceBeamColumn (3-point Gauss-Lobatto; exact for an elastic section) with
  geomTransf Corotational.  Section = elastic (E, A, I) aggregated with a shear
  uniaxialMaterial Elastic of stiffness k G A as 'Vy' (Timoshenko); k = 5/6 and k = 1 are
  computed, plus Euler-Bernoulli (no shear section) for information.
  (The corotational ElasticTimoshenkoBeam is NOT used: it ignores large-displacement
  geometry.)  Large-displacement behaviour is verified by two cantilever checks: the curl
  under a tip moment (exact half circle at M = pi EI / L; the full circle at 2 pi EI / L is
  out of reach because CorotCrdTransf2d measures chord rotations with atan2, i.e. only
  within +-pi, and Newton fails just past the half circle) and the elastica under a dead
  tip force P L^2 / EI = 2 (elliptic integrals and a shooting solution of the extensible,
  shear-deformable rod).
* Mesh: uniform elements of size h on the front beam (120/h elements, h divides 10 and 15);
  the back beam has the same number of elements (size 1.0541 h), so nodes fall at every
  crossbeam attachment b_i = 15 i * 126.4911/120; crossbeam i has round((40 - 5 i)/h)
  elements.  Load points are nodes.  Default sizes h = 2.5 .. 0.15625 (halving); the
  finest gives the stored shapes, the others the convergence tables (error ~ h^2).
* Loads are DEAD nodal loads in world coordinates (Plain pattern, Linear time series):
    L1: (+0.05, 0) at front node s = 60;  L2: (+1.5, 0) at front node s = 60;
    L3: uniform +x on the front beam over s in [75, 105], total 1 N, as nodal loads
        q h on interior nodes and q h / 2 on the two end nodes (q = 1/30 N/mm).
* Solution: static, load control in equal increments, full Newton, NormDispIncr test,
  UmfPack sparse solver.  Limit (fold) loads: displacement control of the x-dof of the load
  node (point load at s = 60) or of the front node at s = 90 (distributed pattern), traced
  past the peak; the peak is located by bisection-like step refinement around the maximum
  and a parabola through the three highest points.

Output conventions (JSON)
-------------------------
* "front"/"back": deformed (x, z) of the centreline at material (undeformed) arc lengths
  s = 0, 10, ..., 120 (back beam also 126.4911, the tip).  Front-beam values are node
  values.  Back-beam nodes are not at multiples of 10, so values are interpolated
  LINEARLY in s between the two neighbouring nodes ("back_interpolation_max_diff_mm" gives
  the largest difference between the linear and a cubic-spline interpolation, an
  estimate of that interpolation error).
* "tip": dx, dz (displacement of the tip node), "rotation" = OpenSees rotation, CCW positive
  in the (x, z) plane seen with x right and z up; "rotation_about_y" = -rotation, i.e. the
  rotation about +y of the right-handed x-y-z frame (a CCW rotation in that view is a
  rotation about -y).
* "reactions": force and moment that the support applies to the beam at each base node
  (OpenSees nodeReaction after reactions()); "My_ccw" is the CCW-positive moment about the
  base point, "My_about_y" = -My_ccw in the spec's y convention.
"""

import argparse
import datetime
import json
import math
import platform
import time
from importlib import metadata

import numpy as np
import openseespy.opensees as ops
from scipy import integrate, interpolate, optimize, special

# ----------------------------------------------------------------------------- data
E_MOD = 12.0
NU = 0.45
G_MOD = E_MOD / (2.0 * (1.0 + NU))
DEPTH = 20.0
T_FRONT = 1.5
T_BACK = 1.5
T_CROSS = 1.0
H_FINGER = 120.0
W_BASE = 40.0
L_FRONT = H_FINGER
L_BACK = math.hypot(W_BASE, H_FINGER)
N_CROSS = 7
Z_CROSS = [15.0 * i for i in range(1, N_CROSS + 1)]

CASES = {
    "L1": {"kind": "point", "s": 60.0, "F": 0.05},
    "L2": {"kind": "point", "s": 60.0, "F": 1.5},
    "L3": {"kind": "dist", "s0": 75.0, "s1": 105.0, "F": 1.0},
}


def area(t):
    return DEPTH * t


def inertia(t):
    return DEPTH * t**3 / 12.0


# ----------------------------------------------------------------------------- model
def define_section(tag, t, shear_k):
    """Elastic section (E, A, I) aggregated with an elastic shear law k G A ('Vy').

    shear_k None -> Euler-Bernoulli (no shear flexibility).  Returns the beamIntegration tag.
    """
    ops.section("Elastic", tag, E_MOD, area(t), inertia(t))
    sec = tag
    if shear_k is not None:
        ops.uniaxialMaterial("Elastic", 1000 + tag, shear_k * G_MOD * area(t))
        ops.section("Aggregator", 100 + tag, 1000 + tag, "Vy", "-section", tag)
        sec = 100 + tag
    ops.beamIntegration("Lobatto", tag, sec, 3)
    return tag


def setup_model():
    ops.wipe()
    ops.model("basic", "-ndm", 2, "-ndf", 3)


class Finger:
    """Builds ref-A in the current OpenSees domain and keeps the node bookkeeping."""

    def __init__(self, h, shear_k, geom="Corotational"):
        n = round(L_FRONT / h)
        if (
            abs(n * h - L_FRONT) > 1e-9
            or abs(10.0 / h - round(10.0 / h)) > 1e-9
            or abs(15.0 / h - round(15.0 / h)) > 1e-9
            or n % 8
        ):
            raise ValueError(f"element size {h} must divide 10 and 15 (and 120/h % 8 == 0)")
        self.h = h
        self.n = n
        setup_model()
        self._tag = 0
        bi_main = define_section(1, T_FRONT, shear_k)
        bi_back = define_section(2, T_BACK, shear_k)
        bi_cross = define_section(3, T_CROSS, shear_k)
        ops.geomTransf(geom, 1)
        # front beam: nodes at s = j h, j = 0..n
        self.front_s = np.arange(n + 1) * h
        self.front = [self._node(0.0, s) for s in self.front_s]
        # back beam: (40,0) -> (0,120), n elements, last node is the tip (shared)
        self.back_s = np.arange(n + 1) * (L_BACK / n)
        self.back = []
        for j in range(n):
            f = j / n
            self.back.append(self._node(W_BASE * (1.0 - f), H_FINGER * f))
        self.tip = self.front[-1]
        self.back.append(self.tip)
        ops.fix(self.front[0], 1, 1, 1)
        ops.fix(self.back[0], 1, 1, 1)
        self._etag = 0
        self._chain(self.front, bi_main)
        self._chain(self.back, bi_back)
        # crossbeams
        self.cross = []
        for i, z in enumerate(Z_CROSS, start=1):
            jf = round(z / h)
            jb = i * n // 8
            a, b = self.front[jf], self.back[jb]
            xa, za = ops.nodeCoord(a)
            xb, zb = ops.nodeCoord(b)
            assert abs(za - z) < 1e-9 and abs(zb - z) < 1e-9 and abs(xa) < 1e-12
            assert abs(xb - W_BASE * (1 - z / H_FINGER)) < 1e-9
            ne = max(1, round((xb - xa) / h))
            nodes = [a] + [self._node(xa + (xb - xa) * k / ne, z) for k in range(1, ne)] + [b]
            self._chain(nodes, bi_cross)
            self.cross.append(nodes)
        self.n_elements = self._etag
        self.n_nodes = self._tag

    def _node(self, x, z):
        self._tag += 1
        ops.node(self._tag, float(x), float(z))
        return self._tag

    def _chain(self, nodes, bi):
        for a, b in zip(nodes[:-1], nodes[1:]):
            self._etag += 1
            ops.element("forceBeamColumn", self._etag, a, b, 1, bi)

    def front_node(self, s):
        j = round(s / self.h)
        assert abs(j * self.h - s) < 1e-9, s
        return self.front[j]

    # ---- loads
    def nodal_loads(self, case, scale=1.0):
        """Nodal loads {node: Fx} (dead, world x) of a load case."""
        c = CASES[case] if isinstance(case, str) else case
        if c["kind"] == "point":
            return {self.front_node(c["s"]): c["F"] * scale}
        q = c["F"] * scale / (c["s1"] - c["s0"])
        j0, j1 = round(c["s0"] / self.h), round(c["s1"] / self.h)
        loads = {}
        for j in range(j0, j1 + 1):
            w = 0.5 if j in (j0, j1) else 1.0
            loads[self.front[j]] = q * self.h * w
        return loads

    def apply_pattern(self, case, scale=1.0, tag=1):
        ops.timeSeries("Linear", tag)
        ops.pattern("Plain", tag, tag)
        for nd, fx in self.nodal_loads(case, scale).items():
            ops.load(nd, fx, 0.0, 0.0)

    # ---- results
    def results(self):
        ops.reactions()
        out = {}
        s_out = np.arange(0.0, L_FRONT + 1e-9, 10.0)
        fx = [ops.nodeCoord(nd, 1) + ops.nodeDisp(nd, 1) for nd in self.front]
        fz = [ops.nodeCoord(nd, 2) + ops.nodeDisp(nd, 2) for nd in self.front]
        idx = [round(s / self.h) for s in s_out]
        out["front"] = {"s": s_out.tolist(), "x": [fx[i] for i in idx], "z": [fz[i] for i in idx]}
        bx = np.array([ops.nodeCoord(nd, 1) + ops.nodeDisp(nd, 1) for nd in self.back])
        bz = np.array([ops.nodeCoord(nd, 2) + ops.nodeDisp(nd, 2) for nd in self.back])
        sb = np.append(np.arange(0.0, L_BACK, 10.0), L_BACK)
        xb_lin, zb_lin = np.interp(sb, self.back_s, bx), np.interp(sb, self.back_s, bz)
        xb_spl = interpolate.CubicSpline(self.back_s, bx)(sb)
        zb_spl = interpolate.CubicSpline(self.back_s, bz)(sb)
        xb_lin[-1], zb_lin[-1] = bx[-1], bz[-1]
        out["back"] = {"s": sb.tolist(), "x": xb_lin.tolist(), "z": zb_lin.tolist()}
        out["back_interpolation"] = "linear in s between nodes (node spacing %.6f mm)" % (
            L_BACK / self.n
        )
        out["back_interpolation_max_diff_mm"] = float(
            np.max(np.hypot(xb_lin - xb_spl, zb_lin - zb_spl))
        )
        rot = ops.nodeDisp(self.tip, 3)
        out["tip"] = {
            "dx": ops.nodeDisp(self.tip, 1),
            "dz": ops.nodeDisp(self.tip, 2),
            "rotation": rot,
            "rotation_about_y": -rot,
        }
        out["reactions"] = {}
        for name, nd in (("front", self.front[0]), ("back", self.back[0])):
            r = ops.nodeReaction(nd)
            out["reactions"][name] = {"Fx": r[0], "Fz": r[1], "My_ccw": r[2], "My_about_y": -r[2]}
        return out


# ----------------------------------------------------------------------------- solution
def static_analysis(integrator_args, tol=1e-11, max_iter=50):
    ops.wipeAnalysis()
    ops.system("UmfPack")
    ops.numberer("RCM")
    ops.constraints("Plain")
    ops.test("NormDispIncr", tol, max_iter, 0)
    ops.algorithm("Newton")
    ops.integrator(*integrator_args)
    ops.analysis("Static")


def solve_case(h, shear_k, case, nsteps, geom="Corotational"):
    """Load-control solution of one case on one mesh.  Returns (finger, results)."""
    fg = Finger(h, shear_k, geom)
    fg.apply_pattern(case)
    static_analysis(("LoadControl", 1.0 / nsteps))
    for step in range(nsteps):
        ok = ops.analyze(1)
        if ok != 0:
            raise RuntimeError(
                f"{case} h={h} k={shear_k}: no convergence at step {step + 1}"
                f" (load factor {ops.getTime():.6f})"
            )
    res = fg.results()
    res["load_factor"] = ops.getTime()
    return fg, res


def equilibrium_check(fg, case):
    """Sum of reactions + applied loads (should be ~0) and moment balance about the origin."""
    ops.reactions()
    loads = fg.nodal_loads(case)
    fx = sum(loads.values())
    m = 0.0
    for nd, f in loads.items():
        z = ops.nodeCoord(nd, 2) + ops.nodeDisp(nd, 2)
        m += -z * f  # CCW moment of a +x force at height z
    rx = rz = rm = 0.0
    for nd in (fg.front[0], fg.back[0]):
        r = ops.nodeReaction(nd)
        x, z = ops.nodeCoord(nd)
        rx += r[0]
        rz += r[1]
        rm += r[2] + x * r[1] - z * r[0]
    return {"sum_Fx": rx + fx, "sum_Fz": rz, "sum_M_origin": rm + m}


def trace_limit(h, shear_k, pattern, ctrl_s, du, u_max, refine=(5, 5, 5)):
    """Displacement control on the x-dof of front node at ctrl_s under the unit `pattern`.

    Traces past the peak of the load factor, then repeats the last stretch with steps
    refined `refine` times until the step is < du / prod(refine) and fits a parabola
    through the three highest points.  Returns dict with the peak and the trace.
    """

    def run(segments, stop_after_peak):
        """segments: list of (n_steps, step) of the control displacement.  A step that
        fails is retried as 4 sub-steps (recursively, down to step / 64).  Returns the
        control displacements, load factors and the list of steps actually taken."""
        fg = Finger(h, shear_k)
        fg.apply_pattern(pattern)
        node = fg.front_node(ctrl_s)
        us, lams, taken = [0.0], [0.0], []

        def step_once(st, depth=0):
            static_analysis(("DisplacementControl", node, 1, st))
            if ops.analyze(1) == 0:
                us.append(ops.nodeDisp(node, 1))
                lams.append(ops.getTime())
                taken.append(st)
                return
            if depth >= 3:
                raise RuntimeError(f"displacement control failed at u={ops.nodeDisp(node, 1)}")
            for _ in range(4):
                step_once(st / 4, depth + 1)

        for nst, st in segments:
            for _ in range(nst):
                step_once(st)
                if stop_after_peak and len(lams) > 3 and lams[-1] < lams[-2]:
                    return np.array(us), np.array(lams), taken
        return np.array(us), np.array(lams), taken

    def compress(steps):
        segs = []
        for st in steps:
            if segs and segs[-1][1] == st:
                segs[-1][0] += 1
            else:
                segs.append([1, st])
        return [tuple(x) for x in segs]

    # coarse trace until the load factor decreases
    us, lams, taken = run([(int(u_max / du), du)], True)
    if not (lams[-1] < lams[-2]):
        raise RuntimeError("no peak found up to u_max")
    coarse = (us.copy(), lams.copy())
    for r in refine:
        i = int(np.argmax(lams))
        # redo the first i - 1 steps (they reach us[i - 1]), then 2 r steps across the peak
        fine = (us[i + 1] - us[i - 1]) / (2 * r)
        us, lams, taken = run(compress(taken[: i - 1]) + [(2 * r, fine)], False)
        step = fine
    i = int(np.argmax(lams))
    u3, l3 = us[i - 1 : i + 2], lams[i - 1 : i + 2]
    c = np.polyfit(u3, l3, 2)
    u_pk = -c[1] / (2 * c[0])
    lam_pk = float(np.polyval(c, u_pk))
    return {
        "peak_load_factor": lam_pk,
        "u_ctrl_at_peak": float(u_pk),
        "max_sampled_load_factor": float(lams[i]),
        "final_step_mm": step,
        "coarse_trace_u": coarse[0].tolist(),
        "coarse_trace_load": coarse[1].tolist(),
    }


# ----------------------------------------------------------------------------- checks
def cantilever(n_el, shear_k, L=100.0, t=1.5):
    setup_model()
    for j in range(n_el + 1):
        ops.node(j + 1, j * L / n_el, 0.0)
    ops.fix(1, 1, 1, 1)
    bi = define_section(1, t, shear_k)
    ops.geomTransf("Corotational", 1)
    for j in range(n_el):
        ops.element("forceBeamColumn", j + 1, j + 1, j + 2, 1, bi)
    return n_el + 1


def check_circle(n_el=50, nsteps=100, shear_k=5 / 6):
    """Tip moment M = 2 pi EI / L: the cantilever should curl into a closed circle.

    OpenSees' CorotCrdTransf2d measures the chord rotation with atan2 relative to the
    undeformed element axis, so it cannot represent an element chord rotated by more than
    pi: the full circle is out of its reach.  We therefore record (a) the exact half circle
    at M = pi EI / L (tip at (0, 2 L / pi), rotation pi) and (b) how far the full-moment
    load goes before Newton fails.
    """
    L, t = 100.0, 1.5
    tip = cantilever(n_el, shear_k, L, t)
    M = 2 * math.pi * E_MOD * inertia(t) / L
    ops.timeSeries("Linear", 1)
    ops.pattern("Plain", 1, 1)
    ops.load(tip, 0.0, 0.0, M)
    static_analysis(("LoadControl", 1.0 / nsteps))
    half, last_ok, failed_at = None, None, None
    for k in range(nsteps):
        if ops.analyze(1) != 0:
            failed_at = ops.getTime()
            break
        last_ok = {
            "load_factor": ops.getTime(),
            "tip_x": L + ops.nodeDisp(tip, 1),
            "tip_y": ops.nodeDisp(tip, 2),
            "tip_rotation": ops.nodeDisp(tip, 3),
        }
        if k + 1 == nsteps // 2:  # half the moment: half circle, tip at (0, 2 L / pi)
            half = {
                "tip_x": L + ops.nodeDisp(tip, 1),
                "tip_y": ops.nodeDisp(tip, 2),
                "tip_rotation": ops.nodeDisp(tip, 3),
                "expected": {"tip_x": 0.0, "tip_y": 2 * L / math.pi, "tip_rotation": math.pi},
            }
    return {
        "n_elements": n_el,
        "load_steps": nsteps,
        "M_full_circle": M,
        "half_circle_M_pi_EI_over_L": half,
        "full_circle_reached": failed_at is None,
        "newton_failed_at_load_factor": failed_at,
        "last_converged": last_ok,
    }


def elastica_exact(alpha):
    """Inextensible, shear-rigid elastica: cantilever, dead tip force perpendicular to the
    undeformed axis, alpha = P L^2 / EI.  Returns (x_tip/L, deflection/L, tip angle)."""

    def fun(phi0):
        m = (1 + math.sin(phi0)) / 2  # k^2
        psi1 = math.asin(1 / math.sqrt(2 * m))
        return special.ellipk(m) - special.ellipkinc(psi1, m) - math.sqrt(alpha)

    phi0 = optimize.brentq(fun, 1e-9, math.pi / 2 - 1e-12, xtol=1e-15)
    m = (1 + math.sin(phi0)) / 2
    psi1 = math.asin(1 / math.sqrt(2 * m))
    x = math.sqrt(2 * math.sin(phi0) / alpha)
    y = 1 - 2 * (special.ellipe(m) - special.ellipeinc(psi1, m)) / math.sqrt(alpha)
    return x, y, phi0


def elastica_reissner(alpha, shear_k, L=100.0, t=1.5):
    """Extensible, shear-deformable planar Reissner rod, same load, by 1-D shooting."""
    EI, EA = E_MOD * inertia(t), E_MOD * area(t)
    GA = (shear_k * G_MOD * area(t)) if shear_k is not None else math.inf
    P = alpha * EI / L**2
    nx, ny = 0.0, -P  # internal force (constant), acting on the part s+ from s-

    def rhs(s, y):
        x, yy, th, m = y
        c, sn = math.cos(th), math.sin(th)
        N = nx * c + ny * sn
        V = -nx * sn + ny * c
        eps, gam = N / EA, V / GA
        dx = (1 + eps) * c - gam * sn
        dy = (1 + eps) * sn + gam * c
        return [dx, dy, m / EI, -(dx * ny - dy * nx)]

    def shoot(m0):
        sol = integrate.solve_ivp(
            rhs, (0, L), [0, 0, 0, m0], rtol=1e-12, atol=1e-12, method="DOP853"
        )
        return sol.y[:, -1]

    m0 = optimize.brentq(lambda m0: shoot(m0)[3], -P * L * 1.2, 0.0, xtol=1e-14)
    x, y, th, _ = shoot(m0)
    return x / L, -y / L, -th


def check_elastica(n_el, shear_k, alpha=2.0, nsteps=50, L=100.0, t=1.5):
    tip = cantilever(n_el, shear_k, L, t)
    P = alpha * E_MOD * inertia(t) / L**2
    ops.timeSeries("Linear", 1)
    ops.pattern("Plain", 1, 1)
    ops.load(tip, 0.0, -P, 0.0)  # dead load, perpendicular to the undeformed axis
    static_analysis(("LoadControl", 1.0 / nsteps))
    for _ in range(nsteps):
        if ops.analyze(1) != 0:
            raise RuntimeError("elastica check failed")
    return {
        "n_elements": n_el,
        "x_tip_over_L": (L + ops.nodeDisp(tip, 1)) / L,
        "deflection_over_L": -ops.nodeDisp(tip, 2) / L,
        "tip_angle": -ops.nodeDisp(tip, 3),
    }


def run_checks():
    out = {}
    t0 = time.time()
    out["circle_tip_moment"] = [check_circle(n, nsteps=100) for n in (20, 50)]
    xe, ye, pe = elastica_exact(2.0)
    out["elastica_alpha_2"] = {
        "exact_inextensible_elliptic": {
            "x_tip_over_L": xe,
            "deflection_over_L": ye,
            "tip_angle": pe,
        },
        "reissner_shooting_k_5_6": dict(
            zip(("x_tip_over_L", "deflection_over_L", "tip_angle"), elastica_reissner(2.0, 5 / 6))
        ),
        "reissner_shooting_EB_extensible": dict(
            zip(("x_tip_over_L", "deflection_over_L", "tip_angle"), elastica_reissner(2.0, None))
        ),
        "opensees_k_5_6": [check_elastica(n, 5 / 6) for n in (20, 40, 80, 160)],
        "opensees_EB": [check_elastica(n, None) for n in (20, 40, 80, 160)],
    }
    out["seconds"] = time.time() - t0
    return out


def cross_checks(h=1.25, case="L2"):
    """Load-step independence and an alternative shear implementation (tip of L2)."""
    out = {}
    for n in (25, 100, 400):
        out[f"load_control_{n}_steps"] = solve_case(h, 5 / 6, case, n)[1]["tip"]
    global define_section
    orig = define_section

    def alt(tag, t, shear_k):
        ops.section("Elastic", tag, E_MOD, area(t), inertia(t), G_MOD, shear_k)
        ops.beamIntegration("Lobatto", tag, tag, 5)
        return tag

    define_section = alt
    try:
        out["section_Elastic_with_G_alphaY_lobatto5"] = solve_case(h, 5 / 6, case, 100)[1]["tip"]
    finally:
        define_section = orig
    return out


# ----------------------------------------------------------------------------- driver
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="tests/data/ref_a_opensees.json")
    ap.add_argument("--sizes", default="2.5,1.25,0.625,0.3125,0.15625")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--no-limit", action="store_true")
    ap.add_argument(
        "--blocks",
        default="k_5_6,k_1,euler_bernoulli",
        help="the section blocks to compute (comma-separated)",
    )
    ap.add_argument(
        "--no-checks",
        action="store_true",
        help="skip the cantilever checks, the cross-checks and the linear-geometry tips",
    )
    args = ap.parse_args(argv)
    blocks = args.blocks.split(",")
    sizes = [float(v) for v in args.sizes.split(",")]
    h_fine = min(sizes)
    t_start = time.time()

    data = {
        "description": "ref-A fin-ray finger, OpenSees 2-D corotational forceBeamColumn "
        "(elastic + shear aggregated section); see script docstring",
        "generator": "tests/reference/opensees_ref_a.py",
        "date": datetime.date.today().isoformat(),
        "versions": {
            "openseespy": metadata.version("openseespy"),
            "opensees": ops.version() if hasattr(ops, "version") else None,
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "units": "mm, N, MPa",
        "conventions": {
            "plane": "OpenSees X = spec x, OpenSees Y = spec z",
            "rotation": "CCW positive in the (x, z) plane viewed with x right, z up",
            "rotation_about_y": "= -rotation (right-handed x-y-z; CCW in that view is about -y)",
            "reactions": "force/moment the support applies to the beam at the base node; "
            "My_ccw CCW positive about the base point, My_about_y = -My_ccw",
            "loads": "dead nodal loads in world coordinates",
            "L3_nodal_loads": "q h on interior nodes, q h / 2 on the end nodes of [75, 105]",
        },
        "model": {
            "E": E_MOD,
            "nu": NU,
            "G": G_MOD,
            "depth": DEPTH,
            "t_front": T_FRONT,
            "t_back": T_BACK,
            "t_cross": T_CROSS,
            "element": "forceBeamColumn, Lobatto 3 points, geomTransf Corotational",
            "section": "Elastic(E,A,I) + Aggregator Vy: uniaxial Elastic k*G*A",
            "solver": "Newton, NormDispIncr 1e-11, UmfPack, load control",
        },
        "load_steps": args.steps,
        "element_size": h_fine,
        "mesh_sizes": sizes,
    }
    if not args.no_checks:
        print("checks ...", flush=True)
        data["large_displacement_checks"] = run_checks()

    for key, kk in (("k_5_6", 5 / 6), ("k_1", 1.0), ("euler_bernoulli", None)):
        if key not in blocks:
            continue
        block = {"shear_k": kk, "element_size": h_fine, "load_steps": args.steps}
        for case in CASES:
            conv = []
            best = None
            sizes_here = sizes if key != "euler_bernoulli" else [h_fine]
            for h in sorted(sizes_here, reverse=True):
                t0 = time.time()
                fg, res = solve_case(h, kk, case, args.steps)
                conv.append(
                    {
                        "h": h,
                        "n_elements": fg.n_elements,
                        "tip_dx": res["tip"]["dx"],
                        "tip_dz": res["tip"]["dz"],
                        "tip_rotation": res["tip"]["rotation"],
                        "seconds": time.time() - t0,
                    }
                )
                if h == h_fine:
                    best = res
                    best["equilibrium_residual"] = equilibrium_check(fg, case)
                print(
                    f"{key} {case} h={h}: dx={res['tip']['dx']:.6f} dz={res['tip']['dz']:.6f}"
                    f" rot={res['tip']['rotation']:.6f} ({time.time() - t0:.1f}s)",
                    flush=True,
                )
            best["element_size"] = h_fine
            best["load_steps"] = args.steps
            best["convergence"] = conv
            if len(conv) >= 2:
                d1, d2 = conv[-1]["tip_dx"], conv[-2]["tip_dx"]
                best["tip_dx_rel_change_last_refinement"] = abs(d1 - d2) / abs(d1)
                best["tip_richardson_h2_extrapolated"] = {
                    q: conv[-1][f"tip_{q}"] + (conv[-1][f"tip_{q}"] - conv[-2][f"tip_{q}"]) / 3.0
                    for q in ("dx", "dz", "rotation")
                }
            block[case] = best
        if not args.no_limit and kk is not None:
            lim = {}
            info = {}
            for name, pat, ctrl, du in (
                ("point_s60", {"kind": "point", "s": 60.0, "F": 1.0}, 60.0, 1.0),
                (
                    "distributed_75_105",
                    {"kind": "dist", "s0": 75.0, "s1": 105.0, "F": 1.0},
                    90.0,
                    1.0,
                ),
            ):
                per_h = []
                for h in sorted(sizes, reverse=True):
                    t0 = time.time()
                    r = trace_limit(h, kk, pat, ctrl, du, u_max=200.0)
                    r["h"] = h
                    r["seconds"] = time.time() - t0
                    per_h.append(r)
                    print(
                        f"{key} limit {name} h={h}: {r['peak_load_factor']:.6f} N at u="
                        f"{r['u_ctrl_at_peak']:.4f} ({r['seconds']:.1f}s)",
                        flush=True,
                    )
                lim[name] = per_h[-1]["peak_load_factor"]
                p1, p2 = per_h[-1]["peak_load_factor"], per_h[-2]["peak_load_factor"]
                lim[name + "_richardson_h2"] = p1 + (p1 - p2) / 3.0
                info[name] = {
                    "control_dof": f"x of front-beam node s={ctrl}",
                    "total_load_N_per_load_factor": 1.0,
                    "mesh_convergence": [
                        {k: v for k, v in r.items() if not k.startswith("coarse")} for r in per_h
                    ],
                    "coarse_trace_finest_mesh": {
                        "u": per_h[-1]["coarse_trace_u"],
                        "load": per_h[-1]["coarse_trace_load"],
                    },
                }
            block["limit_loads"] = lim
            block["limit_load_details"] = info
        data[key] = block

    if not args.no_checks:
        data["cross_checks_h_1.25_k_5_6_L2_tip"] = cross_checks()
        # linear-geometry frame (information only: shows the nonlinearity at L1)
        lin = {}
        for case in CASES:
            _, res = solve_case(h_fine, 5 / 6, case, 1, geom="Linear")
            lin[case] = res["tip"]
        data["linear_geometry_k_5_6_tip_for_information"] = lin
    data["total_seconds"] = time.time() - t_start
    with open(args.out, "w") as f:
        json.dump(data, f, indent=1)
    print("wrote", args.out, f"({time.time() - t_start:.0f}s)")


if __name__ == "__main__":
    main()
