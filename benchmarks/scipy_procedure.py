"""The paper's own solution procedure in plain SciPy: single shooting + fsolve.

This is what a user would write following Sheikh Sofla et al. (2025) in MATLAB or SciPy,
and it is the baseline finray_jax is compared with in `peers.py` and `gradients.py`.
It solves a planar fin-ray finger described by a `finray_jax.Finger` (straight main beams,
clamped bases, no adaptor clamp length, point and distributed loads on the front beam:
enough for ref-A) with

* the same physics as `finray_jax._planar_rod.PlanarRod.rhs`: a planar Cosserat (Reissner) rod
  with state (x, z, theta, nx, nz, my), extension (EA), shear (k G A) and bending (EI);
  theta is the tangent angle measured from +z toward +x; n and m are the internal force
  and moment (world frame) with n' = -f and m' = -(p' x n);
* every beam integrated at fixed steps with a classical Runge-Kutta method (RK4 by
  default; Tsit5 available) between its junctions and load points, `steps` steps per
  piece (10, as finray_jax's default Integrator);
* single shooting: the unknowns are the base wrenches (nx, nz, my) of the front and the
  back beam and the start wrench of every crossbeam at the front beam (3 + 3 + 3 c; 27
  for ref-A). Integrating front beam -> crossbeams -> back beam gives 3 c attachment
  errors (crossbeam end vs back beam) and 6 tip conditions (same position, same relative
  angle, force and moment balance);
* `scipy.optimize.root(method="hybr")` (MINPACK's hybrd: Powell's dogleg with a forward
  finite-difference Jacobian and Broyden updates, the algorithm behind MATLAB's fsolve
  "trust-region-dogleg");
* natural-parameter load stepping (secant predictor from the last two load levels, step
  halved on failure, grown 1.5x on success), because single shooting does not converge
  from the unloaded state at large loads (NUMERICS.md). It is slow: on ref-A L2 (82 % of
  the fold load) it needs ~75 load levels and ~30 000 residuals, on L3 (77 % of its fold)
  ~440 root calls and ~127 000 residuals: the single-shooting Jacobian's condition number
  grows to ~1e8 and hybrd's trust region then admits only short load steps.

Everything is interpreted Python on floats: one residual is a few thousand rhs calls.

Use:
    from scipy_procedure import ShootingModel
    model = ShootingModel.from_finger(fr.ref_finger_a("L2"))
    sol = model.solve()            # -> ShootingSolution (tip, reactions, unknowns, counts)
"""

import dataclasses
import math
import time

import numpy as np
from scipy import optimize

# Butcher tableaux (a, b, c) of the explicit methods offered.
RK4 = (
    ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    (1 / 6, 1 / 3, 1 / 3, 1 / 6),
    (0.0, 0.5, 0.5, 1.0),
)
# Tsitouras 5(4), the solution weights only (as diffrax's Tsit5 steps at fixed h).
_T = (
    (),
    (0.161,),
    (-0.008480655492356989, 0.335480655492357),
    (2.897153057105493, -6.359448489975075, 4.3622954328695815),
    (5.325864828439257, -11.748883564062828, 7.4955393428898365, -0.09249506636175525),
    (
        5.86145544294642,
        -12.92096931784711,
        8.159367898576159,
        -0.071584973281401,
        -0.028269050394068383,
    ),
)
TSIT5 = (
    _T,
    (
        0.09646076681806523,
        0.01,
        0.4798896504144996,
        1.379008574103742,
        -3.290069515436081,
        2.324710524099774,
    ),
    (0.0, 0.161, 0.327, 0.9, 0.9800255409045097, 1.0),
)
METHODS = {"rk4": RK4, "tsit5": TSIT5}


# ----------------------------------------------------------------------------- the rod
def rhs(y, ga, ea, ei, fx, fz):
    """d/ds of the planar Cosserat rod state y = (x, z, theta, nx, nz, my).

    ga = k G A (shear), ea = E A (extension), ei = E I (in-plane bending); (fx, fz) is the
    distributed force per unit length. Identical to finray_jax's PlanarRod.rhs.
    """
    _, _, th, nx, nz, my = y
    c, s = math.cos(th), math.sin(th)
    n1 = c * nx - s * nz  # shear force (along d1 = (cos th, -sin th))
    n3 = s * nx + c * nz  # axial force (along d3 = (sin th, cos th))
    v1 = n1 / ga  # shear strain
    v3 = 1.0 + n3 / ea  # stretch
    dx = c * v1 + s * v3
    dz = -s * v1 + c * v3
    return (dx, dz, my / ei, -fx, -fz, -(dz * nx - dx * nz))


def integrate(y, length, steps, stiff, force, method):
    """Fixed-step explicit Runge-Kutta over one piece of a beam; returns the end state."""
    if length == 0.0:
        return y
    h = length / steps
    args = stiff + force
    if method is RK4:  # the classical method written out on scalars (faster than the tableau loop)
        x, z, th, nx, nz, my = y
        ga, ea, ei, fx, fz = args
        cos, sin = math.cos, math.sin
        h2, h6 = 0.5 * h, h / 6.0

        def d(th, nx, nz, my):  # (x', z', theta', my') of rhs(); n' = -f is constant
            c, s = cos(th), sin(th)
            v1 = (c * nx - s * nz) / ga
            v3 = 1.0 + (s * nx + c * nz) / ea
            dx = c * v1 + s * v3
            dz = -s * v1 + c * v3
            return dx, dz, my / ei, dx * nz - dz * nx

        for _ in range(steps):
            # n is linear in s within a step: n(s + t) = n(s) - f t
            nx2, nz2, nx4, nz4 = nx - h2 * fx, nz - h2 * fz, nx - h * fx, nz - h * fz
            a1, b1, c1, e1 = d(th, nx, nz, my)
            a2, b2, c2, e2 = d(th + h2 * c1, nx2, nz2, my + h2 * e1)
            a3, b3, c3, e3 = d(th + h2 * c2, nx2, nz2, my + h2 * e2)
            a4, b4, c4, e4 = d(th + h * c3, nx4, nz4, my + h * e3)
            x += h6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            z += h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
            th += h6 * (c1 + 2.0 * c2 + 2.0 * c3 + c4)
            my += h6 * (e1 + 2.0 * e2 + 2.0 * e3 + e4)
            nx, nz = nx4, nz4
        return (x, z, th, nx, nz, my)
    a, b, _ = method  # the rhs does not depend on s, so the nodes c are not needed
    for _ in range(steps):
        ks = []
        for ai in a:
            yi = y
            for aij, kj in zip(ai, ks):
                if aij != 0.0:
                    yi = tuple(u + h * aij * v for u, v in zip(yi, kj))
            ks.append(rhs(yi, *args))
        for bi, ki in zip(b, ks):
            if bi != 0.0:
                y = tuple(u + h * bi * v for u, v in zip(y, ki))
    return y


# ----------------------------------------------------------------------------- the finger
@dataclasses.dataclass
class ShootingSolution:
    ok: bool
    unknowns: np.ndarray  # scaled unknowns (27 for ref-A)
    tip_displacement: np.ndarray  # (dx, dz) mm
    tip_rotation_about_y: float  # rad (theta grows with a rotation about +y)
    reaction_front: np.ndarray  # (Fx, Fz, My about +y) applied by the clamp to the beam
    reaction_back: np.ndarray
    max_residual: float
    load_factor: float  # 1 when ok; the last load level reached otherwise
    load_steps: int  # accepted load levels
    root_calls: int  # scipy.optimize.root calls (including failed ones)
    residual_evaluations: int  # total residual evaluations (finite differences included)
    seconds: float


@dataclasses.dataclass
class ShootingModel:
    """A planar finger prepared for single shooting (plain floats, no JAX)."""

    front_base: tuple
    back_base: tuple
    front_theta: float
    back_theta: float
    front_length: float
    back_length: float
    front_stiff: tuple  # (kGA, EA, EI)
    back_stiff: tuple
    cb_front_s: tuple
    cb_back_s: tuple
    cb_theta: tuple  # undeformed crossbeam angles
    cb_length: tuple
    cb_stiff: tuple  # per crossbeam (kGA, EA, EI)
    point_loads: tuple  # ((s, Fx, Fz), ...) on the front beam
    dist_loads: tuple  # ((s0, s1, fx, fz), ...) per unit length, on the front beam
    F: float  # force scale (front EI / L^2)
    L: float  # length scale (front length)
    steps: int = 10
    method: str = "rk4"
    xtol: float = 1e-12  # hybrd's relative step tolerance
    ftol: float = 1e-8  # accepted max |scaled residual| (near L2/L3 hybrd ends at 1e-10..1e-9)
    maxfev: int = 800  # per root call (MINPACK's default, 200 (n + 1), wastes 5600 on a
    #                    load step that is too long; a shorter step is cheaper)

    @classmethod
    def from_finger(cls, finger, steps=10, method="rk4"):
        """Read a finray_jax Finger (straight beams, clamped bases, loads on the front)."""
        import finray_jax as fr

        f = lambda v: float(np.asarray(v))
        arr = lambda v: np.asarray(v, dtype=float)
        if f(finger.front_curvature) or f(finger.back_curvature):
            raise ValueError("straight main beams only")
        ad = finger.adaptor
        if (ad.front_base.name, ad.back_base.name) != ("clamped", "clamped"):
            raise ValueError("clamped bases only")
        if f(ad.front_clamp_length) or f(ad.back_clamp_length):
            raise ValueError("no adaptor clamp length")
        m = finger.material
        E, G, k = f(m.E), f(m.E) / (2 * (1 + f(m.nu))), f(m.shear_coefficient)

        def stiff(t, d):
            return (k * G * t * d, E * t * d, E * d * t**3 / 12.0)

        fb, bb, tip = arr(finger.front_base), arr(finger.back_base), arr(finger.tip)
        lf, lb = float(np.linalg.norm(tip - fb)), float(np.linalg.norm(tip - bb))
        thf = math.atan2(*(tip - fb))  # angle from +z toward +x: atan2(dx, dz)
        thb = math.atan2(*(tip - bb))
        cb = finger.crossbeams
        fs, bs = arr(cb.front_s), arr(cb.back_s)
        pf = fb[None] + fs[:, None] * (tip - fb)[None] / lf
        pb = bb[None] + bs[:, None] * (tip - bb)[None] / lb
        d = pb - pf
        points, dists = [], []
        for load in finger.loads:
            if load.beam != 0:
                raise ValueError("loads on the front beam only")
            if isinstance(load, fr.PointLoad):
                if np.any(arr(load.moment)) or f(load.force[1]):
                    raise ValueError("in-plane point forces only")
                points.append((f(load.s), f(load.force[0]), f(load.force[2])))
            else:
                s0, s1 = arr(load.s_range)
                q = arr(load.total_force) / (s1 - s0)
                dists.append((float(s0), float(s1), float(q[0]), float(q[2])))
        sf = stiff(f(finger.front.thickness), f(finger.front.depth))
        return cls(
            front_base=tuple(fb),
            back_base=tuple(bb),
            front_theta=thf,
            back_theta=thb,
            front_length=lf,
            back_length=lb,
            front_stiff=sf,
            back_stiff=stiff(f(finger.back.thickness), f(finger.back.depth)),
            cb_front_s=tuple(fs),
            cb_back_s=tuple(bs),
            cb_theta=tuple(math.atan2(dx, dz) for dx, dz in d),
            cb_length=tuple(np.linalg.norm(d, axis=1)),
            cb_stiff=tuple(stiff(t, dd) for t, dd in zip(arr(cb.thickness), arr(cb.depth))),
            point_loads=tuple(points),
            dist_loads=tuple(dists),
            F=sf[2] / lf**2,
            L=lf,
            steps=steps,
            method=method,
        )

    @property
    def n_crossbeams(self):
        return len(self.cb_front_s)

    @property
    def n_unknowns(self):
        return 6 + 3 * self.n_crossbeams

    # ---- one sweep over the finger: unknown wrenches -> residual
    def _scale(self):
        F, FL = self.F, self.F * self.L
        return np.array([F, F, FL] * (2 + self.n_crossbeams))

    def sweep(self, u, lam=1.0):
        """Integrate the whole finger for scaled unknowns u at load factor lam.

        Returns (residual, front tip state, front base wrench, back base wrench).
        """
        w = np.asarray(u) * self._scale()
        wf, wb = w[0:3], w[3:6]
        wc = w[6:].reshape(-1, 3)
        meth = METHODS[self.method]
        n, L, F = self.steps, self.L, self.F
        dist = lambda s0, s1: [
            (q[2] * lam, q[3] * lam) for q in self.dist_loads if q[0] <= s0 and s1 <= q[1]
        ]

        # Events on the front beam: crossbeam starts, point loads, ends of distributed loads.
        events = [(s, 1, ("cb", i)) for i, s in enumerate(self.cb_front_s)]
        events += [(p[0], 2, ("point", j)) for j, p in enumerate(self.point_loads)]
        events += [(q[0], 0, ("cut", j)) for j, q in enumerate(self.dist_loads)]
        events += [(q[1], 0, ("cut", j)) for j, q in enumerate(self.dist_loads)]
        events.sort()

        # 1. front beam from its clamped base, with the crossbeams' start wrenches as jumps
        y = (*self.front_base, self.front_theta, *wf)
        s = 0.0
        cb_start = [None] * self.n_crossbeams
        for se, _, (kind, j) in events + [(self.front_length, 9, ("end", 0))]:
            fq = dist(s, se)
            force = (sum(f[0] for f in fq), sum(f[1] for f in fq))
            y = integrate(y, se - s, n, self.front_stiff, force, meth)
            s = se
            x, z, th, nx, nz, my = y
            if kind == "cb":  # crossbeam j starts here with wrench wc[j]
                cb_start[j] = (x, z, th + self.cb_theta[j] - self.front_theta, *wc[j])
                y = (x, z, th, nx - wc[j][0], nz - wc[j][1], my - wc[j][2])
            elif kind == "point":
                p = self.point_loads[j]
                y = (x, z, th, nx - lam * p[1], nz - lam * p[2], my)
        front_tip = y

        # 2. crossbeams from the front beam to the back beam
        cb_end = [
            integrate(cb_start[j], self.cb_length[j], n, self.cb_stiff[j], (0.0, 0.0), meth)
            for j in range(self.n_crossbeams)
        ]

        # 3. back beam from its clamped base; crossbeam end wrenches act on it as jumps
        res = []
        y = (*self.back_base, self.back_theta, *wb)
        s = 0.0
        for j, se in sorted(enumerate(self.cb_back_s), key=lambda t: t[1]):
            y = integrate(y, se - s, n, self.back_stiff, (0.0, 0.0), meth)
            s = se
            x, z, th, nx, nz, my = y
            xe, ze, the, nxe, nze, mye = cb_end[j]
            res += [(xe - x) / L, (ze - z) / L, (the - th) - (self.cb_theta[j] - self.back_theta)]
            y = (x, z, th, nx + nxe, nz + nze, my + mye)
        y = integrate(y, self.back_length - s, n, self.back_stiff, (0.0, 0.0), meth)

        # 4. tip: same point, same relative angle, wrench balance
        xf, zf, thf, nxf, nzf, myf = front_tip
        xb, zb, thb, nxb, nzb, myb = y
        res += [
            (xb - xf) / L,
            (zb - zf) / L,
            (thb - thf) - (self.back_theta - self.front_theta),
            (nxf + nxb) / F,
            (nzf + nzb) / F,
            (myf + myb) / (F * L),
        ]
        return np.asarray(res), front_tip, wf, wb

    def residual(self, u, lam=1.0):
        return self.sweep(u, lam)[0]

    # ---- the solve
    def solve(self, guess=None, max_halvings=12, first_step=1.0, budget_s=None):
        """Root of the residual at full load, by load stepping from `guess` (default: the
        unloaded state, zero wrenches). Returns a ShootingSolution; with `budget_s` (wall
        seconds) it gives up when the budget is spent (ok False, load_factor reached)."""
        t0 = time.perf_counter()
        counts = {"nfev": 0, "calls": 0, "levels": 0}
        u = np.zeros(self.n_unknowns) if guess is None else np.array(guess, dtype=float)
        lam = 0.0 if guess is None else None
        if lam is None:  # warm start: try the full load directly (with MINPACK's default
            # evaluation limit), fall back to stepping from the unloaded state
            u1, ok = self._root(u, 1.0, counts, maxfev=200 * (self.n_unknowns + 1))
            if ok:
                return self._solution(u1, True, counts, t0)
            u, lam = np.zeros(self.n_unknowns), 0.0
        step = first_step
        u_prev, lam_prev = None, None
        while lam < 1.0:
            if budget_s is not None and time.perf_counter() - t0 > budget_s:
                return self._solution(u, False, counts, t0, lam)
            target = min(1.0, lam + step)
            guess_u = u
            if u_prev is not None:  # secant predictor from the last two load levels
                guess_u = u + (u - u_prev) * (target - lam) / (lam - lam_prev)
            u1, ok = self._root(guess_u, target, counts)
            if ok:
                u_prev, lam_prev, u, lam = u, lam, u1, target
                counts["levels"] += 1
                step = min(1.5 * step, 1.0)
            else:
                step *= 0.5
                if step < first_step * 0.5**max_halvings:
                    return self._solution(u, False, counts, t0, lam)
        return self._solution(u, True, counts, t0)

    def _root(self, u0, lam, counts, maxfev=None):
        sol = optimize.root(
            self.residual,
            u0,
            args=(lam,),
            method="hybr",
            options={"xtol": self.xtol, "maxfev": maxfev or self.maxfev},
        )
        counts["nfev"] += sol.nfev
        counts["calls"] += 1
        # hybrd may stop with "not making good progress" at a root already accurate to
        # rounding: judge by the residual itself.
        ok = bool(np.all(np.isfinite(sol.x))) and float(np.max(np.abs(sol.fun))) < self.ftol
        return sol.x, ok

    def _solution(self, u, ok, counts, t0, lam=1.0):
        r, tip, wf, wb = self.sweep(u, lam)
        x0, z0 = self.front_base
        tip0 = (
            x0 + self.front_length * math.sin(self.front_theta),
            z0 + self.front_length * math.cos(self.front_theta),
        )
        return ShootingSolution(
            ok=ok,
            unknowns=u,
            tip_displacement=np.array([tip[0] - tip0[0], tip[1] - tip0[1]]),
            tip_rotation_about_y=tip[2] - self.front_theta,
            # The clamp applies -(n(0), m(0)) to the beam (finray_jax's Reaction); my is the
            # y component of m.
            reaction_front=-np.asarray(wf),
            reaction_back=-np.asarray(wb),
            max_residual=float(np.max(np.abs(r))),
            load_factor=lam,
            load_steps=counts["levels"],
            root_calls=counts["calls"],
            residual_evaluations=counts["nfev"],
            seconds=time.perf_counter() - t0,
        )


if __name__ == "__main__":
    import finray_jax as fr

    for case in ("L1", "L2", "L3"):
        model = ShootingModel.from_finger(fr.ref_finger_a(case))
        sol = model.solve()
        print(
            case,
            sol.ok,
            sol.tip_displacement,
            sol.reaction_front,
            f"{sol.seconds:.2f} s",
            f"{sol.load_steps} levels, {sol.root_calls} root calls, "
            f"{sol.residual_evaluations} residuals, max|r| {sol.max_residual:.1e}",
        )
