"""ref-A in PyElastica: Cosserat rods joined by FixedJoints, relaxed to statics by damping.

PyElastica (pip `pyelastica`) integrates the *dynamics* of discrete Cosserat rods with an
explicit symplectic stepper; a static equilibrium is what is left after the motion has
been damped out. This module builds a planar finger given as a `finray_jax.Finger` (straight
main beams, clamped bases, loads on the front beam; ref-A) in PyElastica and relaxes it.

Model
-----
* Nine rods in the x-z plane (y out of plane): front beam, back beam, one per crossbeam.
  Directors: d1 = +y (so in-plane bending is about d1), d2 = d3 x d1, d3 = tangent.
* PyElastica assumes circular sections; the shear/stretch and bend/twist matrices are
  overwritten with the rectangle's: diag(kGA, kGA, EA) and diag(E d t^3/12, E t d^3/12,
  G (Ixx + Iyy)) (torsion as finray_jax's default "paper" constant).
* Joints: `FixedJoint` (a penalty spring on the node positions and a rotational spring on
  the element directors, with the rest relative rotation of the undeformed finger). A
  FixedJoint couples the directors of *elements*, whose centres lie half an element from
  the joint node, and the clamp (`OneEndFixedBC`) holds the first element's director; so
  every joint and clamp gets a short element (`short` x the element size) next to it,
  otherwise the finger comes out too stiff (NUMERICS.md: a cantilever 12 % stiff).
* Loads: dead nodal forces in world coordinates (a custom `NoForces` subclass), ramped
  up over `ramp` time units; a distributed load is lumped to the nodes (lengths of the
  adjacent half elements inside the loaded range).
* Statics by dynamic relaxation: the density, node masses and element inertias are free
  (they do not change the equilibrium), so they are chosen per node and element from the
  local stiffness (Gershgorin bound) such that every node and element has about the same
  highest frequency: the short elements and stiff joint springs then do not shrink the
  stable time step. `AnalyticalLinearDamper` (uniform damping constant) removes the
  kinetic energy; the constant is a fraction of the estimated lowest frequency.

Use:
    fe = ElasticaFinger(fr.ref_finger_a("L1"), dx=1.25)   # 343 elements
    out = fe.relax(budget_s=60, reference_tip=(dx, dz))   # history of tip vs wall time
"""

import dataclasses
import math
import time

import elastica as ea
import numpy as np


class _Sim(
    ea.BaseSystemCollection,
    ea.Connections,
    ea.Constraints,
    ea.Forcing,
    ea.Damping,
):
    pass


class NodalForces(ea.NoForces):
    """Dead world-frame forces at given nodes, ramped linearly from 0 over `ramp`."""

    def __init__(self, nodes, forces, ramp):
        super().__init__()
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.forces = np.asarray(forces, dtype=np.float64).T  # (3, k)
        self.ramp = float(ramp)

    def apply_forces(self, system, time=np.float64(0.0)):
        factor = min(1.0, float(time) / self.ramp) if self.ramp > 0 else 1.0
        system.external_forces[:, self.nodes] += factor * self.forces


def _nodes(length, marks, dx, short):
    """Node arc lengths on [0, length]: a node at every mark, a short element of length
    `short` after each mark in `after` and before each mark in `before`, elements of about
    dx elsewhere. marks: dict s -> ('after' | 'before' | None)."""
    keys = sorted(set([0.0, length] + list(marks)))
    s_nodes = []
    for a, b in zip(keys[:-1], keys[1:]):
        lo, hi = a, b
        s_nodes.append(a)
        if marks.get(a) == "after":
            s_nodes.append(a + short)
            lo = a + short
        tail = []
        if marks.get(b) == "before":
            tail = [b - short]
            hi = b - short
        n = max(1, round((hi - lo) / dx))
        s_nodes += list(lo + (hi - lo) * np.arange(1, n) / n)
        if tail:
            s_nodes.append(lo + (hi - lo))
    s_nodes.append(keys[-1])
    s = np.asarray(s_nodes)
    # drop duplicates (a 'before' short element right after the previous mark)
    keep = np.concatenate([[True], np.diff(s) > 1e-12])
    return s[keep]


@dataclasses.dataclass
class Beam:
    s: np.ndarray  # node arc lengths
    base: np.ndarray  # (x, z)
    direction: np.ndarray  # unit (x, z)
    t: float
    d: float
    rod: object = None

    def node(self, s):
        i = int(np.argmin(np.abs(self.s - s)))
        assert abs(self.s[i] - s) < 1e-9, (s, self.s[i])
        return i


class ElasticaFinger:
    def __init__(
        self,
        finger,
        dx=1.25,
        short=0.1,
        joint_k=10.0,
        joint_kt=200.0,
        damping=8.0,
        ramp_periods=0.3,
        dt_safety=0.5,
    ):
        """finger: a finray_jax Finger (ref-A-like). dx: element size (mm); short: length
        of the elements next to joints and clamps, as a fraction of dx; joint_k, joint_kt:
        joint springs in units of EA/dx and EI/dx of the front beam; damping: damping
        constant as a multiple of the estimated lowest frequency; ramp_periods: load ramp
        time in lowest periods / (2 pi); dt_safety: time step as a fraction of 2/omega_max.
        """
        import finray_jax as fr

        f = lambda v: float(np.asarray(v))
        arr = lambda v: np.asarray(v, dtype=float)
        m = finger.material
        self.E, self.nu, self.k = f(m.E), f(m.nu), f(m.shear_coefficient)
        self.G = self.E / (2 * (1 + self.nu))
        self.dx = dx
        eps = short * dx
        fb, bb, tip = arr(finger.front_base), arr(finger.back_base), arr(finger.tip)
        lf, lb = float(np.linalg.norm(tip - fb)), float(np.linalg.norm(tip - bb))
        cb = finger.crossbeams
        fs, bs = arr(cb.front_s), arr(cb.back_s)
        self.front_s, self.back_s = fs, bs

        point, dist = [], []
        for load in finger.loads:
            assert load.beam == 0, "loads on the front beam only"
            if isinstance(load, fr.PointLoad):
                point.append((f(load.s), arr(load.force)))
            else:
                s0, s1 = arr(load.s_range)
                dist.append((float(s0), float(s1), arr(load.total_force) / (s1 - s0)))

        marks_f = {0.0: "after", lf: "before"}
        marks_f.update({float(s): "after" for s in fs})
        for s, _ in point:
            marks_f.setdefault(s, None)
        for s0, s1, _ in dist:
            marks_f.setdefault(s0, None)
            marks_f.setdefault(s1, None)
        marks_b = {0.0: "after", lb: "before"}
        marks_b.update({float(s): "after" for s in bs})
        self.front = Beam(
            _nodes(lf, marks_f, dx, eps),
            fb,
            (tip - fb) / lf,
            f(finger.front.thickness),
            f(finger.front.depth),
        )
        self.back = Beam(
            _nodes(lb, marks_b, dx, eps),
            bb,
            (tip - bb) / lb,
            f(finger.back.thickness),
            f(finger.back.depth),
        )
        self.cross = []
        for a, b, t, d in zip(fs, bs, arr(cb.thickness), arr(cb.depth)):
            pa = fb + a * (tip - fb) / lf
            pb = bb + b * (tip - bb) / lb
            lc = float(np.linalg.norm(pb - pa))
            self.cross.append(
                Beam(
                    _nodes(lc, {0.0: "after", lc: "before"}, dx, eps),
                    pa,
                    (pb - pa) / lc,
                    float(t),
                    float(d),
                )
            )

        # scales for the joint springs and the time step
        A, I = self.front.t * self.front.d, self.front.d * self.front.t**3 / 12
        self.kj = joint_k * self.E * A / dx
        self.ktj = joint_kt * self.E * I / dx
        self.rho = 1.0  # arbitrary: statics does not depend on it (time unit follows)
        self.omega_max = 2.0 * math.sqrt(self.E / self.rho) / dx
        self.dt = dt_safety * 2.0 / self.omega_max
        self.damping_multiple = damping
        self.ramp_periods = ramp_periods
        self.point, self.dist = point, dist
        self._build()

    # ------------------------------------------------------------------ building
    def _make_rod(self, beam: Beam):
        x = beam.base[0] + beam.s * beam.direction[0]
        z = beam.base[1] + beam.s * beam.direction[1]
        pos = np.stack([x, np.zeros_like(x), z])
        n = len(beam.s) - 1
        direction = np.array([beam.direction[0], 0.0, beam.direction[1]])
        rod = ea.CosseratRod.straight_rod(
            n,
            pos[:, 0],
            direction,
            np.array([0.0, 1.0, 0.0]),
            float(beam.s[-1]),
            base_radius=1.0,
            density=self.rho,
            youngs_modulus=self.E,
            shear_modulus=self.G,
            position=pos,
        )
        t, d = beam.t, beam.d
        A = t * d
        I_in, I_out = d * t**3 / 12, t * d**3 / 12  # about d1 (= y) and about d2
        J = I_in + I_out  # finray_jax's default torsion constant ("paper")
        ell = np.diff(beam.s)
        rod.shear_matrix[:] = 0.0
        rod.shear_matrix[0, 0] = rod.shear_matrix[1, 1] = self.k * self.G * A
        rod.shear_matrix[2, 2] = self.E * A
        rod.bend_matrix[:] = 0.0
        rod.bend_matrix[0, 0] = self.E * I_in
        rod.bend_matrix[1, 1] = self.E * I_out
        rod.bend_matrix[2, 2] = self.G * J
        beam.rod = rod
        beam.stiff = dict(
            EA=self.E * A,
            GA=self.k * self.G * A,
            B=np.array([self.E * I_in, self.E * I_out, self.G * J]),
            Iphys=np.array([I_in, I_out, J]),
            ell=ell,
        )
        # fictitious inertia, completed once the joints are known (_scale_inertia)
        beam.extra_k = np.zeros(n + 1)  # joint translational springs per node
        beam.extra_kt = np.zeros(n)  # joint rotational springs per element
        return rod

    def _scale_inertia(self, beam: Beam):
        """Node masses and element inertias from the local stiffness (Gershgorin), so
        that no node or element is faster than omega_max (dynamic relaxation masses)."""
        rod, st = beam.rod, beam.stiff
        ell = st["ell"]
        w2 = self.omega_max**2
        kax = st["EA"] / ell  # axial springs per element (the stiffest translation)
        ksum = np.zeros(len(ell) + 1)
        ksum[:-1] += kax
        ksum[1:] += kax
        mass = 2.0 * (ksum + beam.extra_k) / w2
        phys = np.zeros_like(mass)
        phys[:-1] += 0.5 * self.rho * beam.t * beam.d * ell
        phys[1:] += 0.5 * self.rho * beam.t * beam.d * ell
        rod.mass[:] = np.maximum(mass, phys)
        # rotations: bending couples at the Voronoi points, shear lever, joint springs
        lv = 0.5 * (ell[1:] + ell[:-1])
        krot = np.zeros((3, len(ell)))
        for a in range(3):
            kb = 2.0 * st["B"][a] / lv
            krot[a, :-1] += kb
            krot[a, 1:] += kb
        krot[0] += st["GA"] * ell
        krot[1] += st["GA"] * ell
        krot += 2.0 * beam.extra_kt[None]
        inertia = np.maximum(2.0 * krot / w2, self.rho * st["Iphys"][:, None] * ell[None])
        rod.mass_second_moment_of_inertia[:] = 0.0
        rod.inv_mass_second_moment_of_inertia[:] = 0.0
        for a in range(3):
            rod.mass_second_moment_of_inertia[a, a] = inertia[a]
            rod.inv_mass_second_moment_of_inertia[a, a] = 1.0 / inertia[a]

    def _joint(self, sim, b1: Beam, i1, b2: Beam, i2):
        r1, r2 = b1.rod, b2.rod
        rest = r1.director_collection[..., i1] @ r2.director_collection[..., i2].T
        sim.connect(r1, r2, first_connect_idx=i1, second_connect_idx=i2).using(
            ea.FixedJoint,
            k=self.kj,
            nu=0.0,
            kt=self.ktj,
            nut=0.0,
            rest_rotation_matrix=rest,
        )
        for b, i in ((b1, i1), (b2, i2)):
            b.extra_k[i] += self.kj
            b.extra_kt[i] += self.ktj

    def _build(self):
        sim = _Sim()
        beams = [self.front, self.back] + self.cross
        for b in beams:
            sim.append(self._make_rod(b))
        for j, cbeam in enumerate(self.cross):
            self._joint(sim, self.front, self.front.node(self.front_s[j]), cbeam, 0)
            self._joint(sim, self.back, self.back.node(self.back_s[j]), cbeam, -1)
        self._joint(sim, self.front, -1, self.back, -1)
        for b in (self.front, self.back):
            sim.constrain(b.rod).using(
                ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,)
            )
        for b in beams:
            self._scale_inertia(b)
        # frequency scale: the cantilever-like first mode of the front beam,
        # omega_1 ~ 3.5 sqrt(EI / (m L^4)) with the (scaled) mass per length. The finger's
        # lowest mode is ~4x higher (measured from the free oscillation of ref-A L1), so
        # damping = 8 omega_1 is about critical for it.
        fr_ = self.front
        m_per_len = fr_.rod.mass.sum() / fr_.s[-1]
        L = fr_.s[-1]
        self.omega_1 = 3.52 * math.sqrt(fr_.stiff["B"][0] / (m_per_len * L**4))
        gamma = self.damping_multiple * self.omega_1
        for b in beams:
            sim.dampen(b.rod).using(
                ea.AnalyticalLinearDamper, uniform_damping_constant=gamma, time_step=self.dt
            )
        nodes, forces = [], []
        for s, F in self.point:
            nodes.append(self.front.node(s))
            forces.append(F)
        for s0, s1, q in self.dist:
            s = self.front.s
            left = np.concatenate([[0.0], np.diff(s)]) * 0.5
            right = np.concatenate([np.diff(s), [0.0]]) * 0.5
            inside_l = (s > s0 + 1e-9) & (s <= s1 + 1e-9)
            inside_r = (s >= s0 - 1e-9) & (s < s1 - 1e-9)
            w = left * inside_l + right * inside_r
            for i in np.nonzero(w)[0]:
                nodes.append(int(i))
                forces.append(q * w[i])
        self.ramp = self.ramp_periods / self.omega_1
        if nodes:
            sim.add_forcing_to(self.front.rod).using(NodalForces, nodes, forces, self.ramp)
        sim.finalize()
        self.sim = sim
        self.stepper = ea.PositionVerlet()
        self.time = np.float64(0.0)
        self.tip0 = self.front.rod.position_collection[[0, 2], -1].copy()

    @property
    def n_elements(self):
        return sum(len(b.s) - 1 for b in [self.front, self.back] + self.cross)

    def tip(self):
        return self.front.rod.position_collection[[0, 2], -1] - self.tip0

    # ------------------------------------------------------------------ relaxing
    def relax(self, budget_s, reference_tip=None, chunk=2000, tol=5e-3, settle=1e-5):
        """Step until `budget_s` of wall time is spent or the motion has settled (the tip
        moved by less than `settle` x |tip| over the last chunk, after the ramp).

        Returns a dict: history of (wall s, steps, tip dx, dz, relative difference to
        reference_tip), the time at which the tip entered and stayed within `tol` of the
        reference, the final tip and the step count."""
        ref = None if reference_tip is None else np.asarray(reference_tip, dtype=float)
        hist = []
        t0 = time.perf_counter()
        steps = 0
        prev = self.tip().copy()
        settled_at = None
        while True:
            for _ in range(chunk):
                self.time = self.stepper.step(self.sim, self.time, self.dt)
            steps += chunk
            wall = time.perf_counter() - t0
            tip = self.tip().copy()
            if not np.all(np.isfinite(tip)):
                hist.append((wall, steps, float("nan"), float("nan"), float("nan")))
                break
            rel = (
                float(np.linalg.norm(tip - ref) / np.linalg.norm(ref))
                if ref is not None
                else float("nan")
            )
            hist.append((wall, steps, float(tip[0]), float(tip[1]), rel))
            moved = float(np.linalg.norm(tip - prev)) / max(float(np.linalg.norm(tip)), 1e-12)
            prev = tip
            if self.time > self.ramp and moved < settle and settled_at is None:
                settled_at = (wall, steps)
                break
            if wall > budget_s:
                break
        within = None
        if ref is not None:
            for k in range(len(hist)):
                if all(h[4] < tol for h in hist[k:]):
                    within = {"wall_s": hist[k][0], "steps": hist[k][1]}
                    break
        return {
            "history": hist,
            "within_tol": within,
            "settled": None
            if settled_at is None
            else {"wall_s": settled_at[0], "steps": settled_at[1]},
            "tip": hist[-1][2:4],
            "rel_diff": hist[-1][4],
            "steps": steps,
            "wall_s": hist[-1][0],
            "dt": float(self.dt),
            "time_per_step_us": 1e6 * hist[-1][0] / max(steps, 1),
        }
