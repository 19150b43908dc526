"""Elastic stability of an equilibrium: the tangent stiffness of the shooting problem.

An equilibrium is stable when the second variation of the potential energy (strain
energy, penalty contact, dead loads) is positive for every admissible variation. Cut the
finger at its shooting nodes (the segments' ends, joined where the residual's kinematic
rows join them): the second variation is then positive if and only if

1. every segment, held at both ends, is stable by itself: along the segment the block
   B(s) = d(position, angle)(s) / d(force, moment)(start) of its flow Jacobian stays
   non-singular (no conjugate point; det B > 0 just after the start, so a sign change
   anywhere on (0, l] is one), and
2. the condensed stiffness K of the nodes, under the imposed displacements (clamped and
   pinned bases, the objects where they are), is positive definite.

That is the Schur complement of the energy's Hessian on the segments' interiors, so the
two tests together are exact for the discrete model (its flow Jacobians are those of the
integration the solver uses). A segment with flow Jacobian [[A, B], [C, D]] (kinematics
k = (x, z, theta), wrench w = (nx, nz, my), end from start) has end wrenches
w0 = B^-1 (k1 - A k0) and w1 = C k0 + D w0; the wrenches the nodes apply to it, (-w0, w1),
differentiated in (k0, k1), give its 6 x 6 stiffness, and K is their sum over the nodes.
Penalty contact is conservative, so K is symmetric to the integration's error; friction is
not, and the test then reads the symmetric part (the quasi-static energy test, with the
friction's stiffness averaged).

K is reported in the scaled coordinates (x / L, z / L, theta) and over F L, with L and F
the solver's length and force scales (the front beam's length, and its EI / L^2): its
eigenvalues are dimensionless, of order 1 for an unloaded finger, and a fold or a
bifurcation is where the smallest one passes 0.
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from ._finger import FingerError
from ._flow import flow_jacobians
from ._members import energy
from ._solve import make_problem

KIN = slice(0, 3)  # (x, z, theta) in a planar state
WRENCH = slice(3, 6)  # (nx, nz, my)


@dataclasses.dataclass(frozen=True)
class Stability:
    """Whether an equilibrium is stable, and its softest mode.

    stable: no conjugate point inside a segment and the condensed tangent stiffness is
        positive definite.
    min_eigenvalue: the smallest eigenvalue of the condensed stiffness (dimensionless,
        see the module's note): negative on an unstable equilibrium, near 0 near a fold or
        a bifurcation.
    eigenvalues: the smallest few, ascending.
    conjugate_segments: segments that buckle with both ends held (empty when none).
    asymmetry: ||K - K^T|| / ||K||: the integration's error without friction, the
        friction's non-conservative part with it.
    modes: (k, n_nodes, 3) the eigenvectors of `eigenvalues` as node displacements (x, z
        in mm; theta in rad), each scaled so that its largest entry in the scaled
        coordinates is 1.
    perturbations: (k, *unknowns.shape) the scaled shooting unknowns' change that moves
        the nodes along each mode (each segment's start wrench from its two ends): a start
        for Newton off this equilibrium toward a neighbouring branch.
    """

    stable: bool
    min_eigenvalue: float
    eigenvalues: np.ndarray
    conjugate_segments: tuple[int, ...]
    asymmetry: float
    modes: np.ndarray
    perturbations: np.ndarray

    @property
    def message(self) -> str:
        if self.stable:
            return ""
        why = []
        if self.min_eigenvalue < 0:
            why.append(
                f"the tangent stiffness has a negative eigenvalue ({self.min_eigenvalue:.3g})"
            )
        if self.conjugate_segments:
            why.append(f"segments {list(self.conjugate_segments)} buckle with both ends held")
        return "unstable equilibrium: " + "; ".join(why)


class _Nodes:
    """The shooting nodes: classes of segment slots (slot i the start of segment i, S + i
    its end) that the kinematic rows make one point, and their fixed directions."""

    def __init__(self, topo, L, length, rigid):
        S = topo.n_segments
        parent = list(range(2 * S))

        def find(a):
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        def union(a, b):
            parent[find(a)] = find(b)

        ix = topo.index
        for a, b in zip(ix.kin_a, ix.kin_b):
            union(int(a), int(b))
        tiny = 1e-12 * L
        flexible = np.asarray(length - rigid) > tiny
        for i in np.flatnonzero(~flexible):
            if float(rigid[i]) <= tiny:  # a zero-length segment: its ends are one point
                union(i, S + i)
        roots = sorted({find(a) for a in range(2 * S)})
        number = {r: n for n, r in enumerate(roots)}
        self.of = np.asarray([number[find(a)] for a in range(2 * S)])
        self.count = len(roots)
        fixed = np.zeros((self.count, 3), dtype=bool)
        for b in (0, 1):
            kind = topo.base_kinds[b]
            node = self.of[topo.first[b]]
            fixed[node] |= np.asarray(kind.fixed)
        # A segment held rigidly over its whole length (inside a clamp, which starts at a
        # clamped base) carries its start's fixing to its end.
        rigid_whole = [i for i in np.flatnonzero(~flexible) if float(rigid[i]) > tiny]
        changed = True
        while changed:
            changed = False
            for i in rigid_whole:
                a, b = self.of[i], self.of[S + i]
                if fixed[a].all() and not fixed[b].all():
                    fixed[b] = True
                    changed = True
        for i in rigid_whole:
            if not fixed[self.of[i]].all():
                raise FingerError(
                    f"segment {i} is held rigidly but its start is not fixed: a clamped "
                    "length needs a clamped base"
                )
        self.fixed = fixed
        self.flexible = flexible


def _full_jacobian(jac, translation_free):
    """(..., 6, 6) d(x, z, theta, nx, nz, my)(s) / d(same)(start) from a flow Jacobian in
    the start state's tangent coordinates (without the two translations when the flow
    commutes with them: those columns are then the identity on the position)."""
    rows = jac[..., :6, :]
    if not translation_free:
        return rows
    shape = rows.shape[:-1] + (2,)
    trans = np.zeros(shape)
    trans[..., 0, 0] = 1.0
    trans[..., 1, 1] = 1.0
    return np.concatenate([trans, rows], axis=-1)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _at_equilibrium(topo, integrator, finger, Y, lam):
    """Every segment's flow Jacobian at every step point, (S, steps + 1, n_full, k), with
    the contact law on every segment (exact where none acts); the unknowns' scale, the
    segments' lengths and rigid parts, and the length and force scales."""
    problem = make_problem(topo, integrator, finger)
    Y = jnp.reshape(Y, (topo.n_segments, -1))
    starts = problem.start_states(Y)
    Q = problem.params(lam)
    states, jac = flow_jacobians(problem.model, integrator, starts, Q, True, False, True)[:2]
    t = problem.table
    members = None
    if topo.members is not None:
        members = _member_hessian(problem, starts, states[:, -1])
    return jac, problem.scale(), t.length, t.rigid, problem.geo.L, problem.geo.F, members


def _member_hessian(problem, starts, ends):
    """The Hessian of the members' contact energy in the (x, z, theta) of every slot:
    (2 S, 3, 2 S, 3). Their contact reads the slots' kinematics only."""
    kin, *rest = problem.member_args(starts, ends)
    return jax.hessian(energy, argnums=1)(problem.topo.members, kin, *rest)


def stability_of(topo, integrator, finger, Y, lam=1.0, n_eigenvalues: int = 4) -> Stability:
    """The stability of the equilibrium of `finger` with scaled unknowns Y on the segment
    table `topo` (eager)."""
    if topo.mode != "planar":
        raise FingerError(
            f"stability is computed for planar fingers (mode='planar'), got mode={topo.mode!r}"
        )
    out = _at_equilibrium(topo, integrator, finger, jnp.asarray(Y), jnp.asarray(lam, float))
    jac, y_scale, length, rigid = (np.asarray(x) for x in out[:4])
    L, F = (float(x) for x in out[4:6])
    jac = _full_jacobian(jac, topo.model.translation_free)
    nodes = _Nodes(topo, L, length, rigid)
    S = topo.n_segments
    extra = None
    if out[6] is not None:
        extra = _member_stiffness(nodes, np.asarray(out[6]), np.array([L, L, 1.0]), F * L)
    out = condensed_stability(
        jac,
        nodes.of[:S],
        nodes.of[S:],
        nodes.fixed,
        nodes.flexible,
        kin_scale=np.array([L, L, 1.0]),
        wrench_scale=np.array([F, F, F * L]),
        y_scale=np.asarray(y_scale),
        n_eigenvalues=n_eigenvalues,
        extra=extra,
    )
    shape = (out.perturbations.shape[0],) + np.shape(Y)
    return dataclasses.replace(out, perturbations=out.perturbations.reshape(shape))


def _member_stiffness(nodes: _Nodes, hessian, kin_scale, unit):
    """The members' contact stiffness on the node coordinates (scaled as K): the
    energy's Hessian in the slots' kinematics, summed over the slots of each node."""
    n = nodes.count
    K = np.zeros((n, 3, n, 3))
    three = np.arange(3)
    index = (nodes.of[:, None, None, None], three[None, :, None, None])
    index += (nodes.of[None, None, :, None], three[None, None, None, :])
    np.add.at(K, index, hessian)
    K *= kin_scale[None, :, None, None] * kin_scale[None, None, None, :] / unit
    return K.reshape(3 * n, 3 * n)


def condensed_stability(
    jac,
    start_node,
    end_node,
    fixed,
    flexible,
    kin_scale,
    wrench_scale,
    y_scale,
    n_eigenvalues=4,
    extra=None,
) -> Stability:
    """The two tests of the module's note, from every segment's flow Jacobian at its step
    points, jac (S, n + 1, 6, 6) in (x, z, theta, nx, nz, my); the nodes of its start and
    end (S,); fixed (n_nodes, 3): the imposed directions; flexible (S,): segments with a
    flexible part (the others join or fix their ends). Scales: of the kinematics, the
    wrench and the unknowns (Y = y / y_scale). extra: a stiffness to add to K (scaled as
    K: the members' contact)."""
    S = jac.shape[0]
    n_nodes = fixed.shape[0]
    unit = wrench_scale[0] * kin_scale[0]  # F L

    # 1. Conjugate points: det of the scaled B(s) at every step point after the start.
    B = jac[:, 1:, KIN, WRENCH] * wrench_scale[None, None, None, :]
    B = B / kin_scale[None, None, :, None]
    det = np.linalg.det(B)
    conjugate = tuple(int(i) for i in np.flatnonzero(flexible & np.any(det <= 0, axis=1)))

    # 2. The condensed stiffness, in scaled node coordinates.
    seg = np.flatnonzero(flexible)
    phi = jac[seg, -1]
    A, C, D = phi[:, KIN, KIN], phi[:, WRENCH, KIN], phi[:, WRENCH, WRENCH]
    Binv = np.linalg.inv(phi[:, KIN, WRENCH])
    BA = Binv @ A
    Ke = np.empty((seg.size, 6, 6))
    Ke[:, :3, :3], Ke[:, :3, 3:] = BA, -Binv
    Ke[:, 3:, :3], Ke[:, 3:, 3:] = C - D @ BA, D @ Binv
    scale = np.concatenate([kin_scale, kin_scale])
    Ke *= scale[:, None] * scale[None, :] / unit
    three = np.arange(3)
    dofs = np.concatenate(
        [3 * start_node[seg, None] + three, 3 * end_node[seg, None] + three], axis=1
    )
    K = np.zeros((3 * n_nodes, 3 * n_nodes))
    np.add.at(K, (dofs[:, :, None], dofs[:, None, :]), Ke)
    if extra is not None:
        K += extra
    free = np.flatnonzero(~fixed.reshape(-1))
    Kf = K[np.ix_(free, free)]
    norm = max(np.linalg.norm(Kf), np.finfo(float).tiny)
    asymmetry = float(np.linalg.norm(Kf - Kf.T) / norm)
    k = min(n_eigenvalues, free.size)
    values, vectors = np.zeros(0), np.zeros((free.size, 0))
    if k:  # (the smallest k only: a partial decomposition)
        values, vectors = scipy.linalg.eigh(
            0.5 * (Kf + Kf.T), subset_by_index=(0, k - 1), driver="evx"
        )
    V = np.zeros((k, 3 * n_nodes))
    V[:, free] = (vectors / np.max(np.abs(vectors), axis=0)).T
    modes = V.reshape(k, -1, 3) * kin_scale

    # The unknowns' change along each mode: each flexible segment's start wrench from its
    # two ends' displacements (0 on the rest, whose wrench the kinematics do not fix).
    dY = np.zeros((k, S, 6))
    dY[:, :, KIN] = modes[:, start_node]
    dk = modes[:, end_node[seg]] - np.einsum("sij,ksj->ksi", A, modes[:, start_node[seg]])
    dY[:, seg, WRENCH] = np.einsum("sij,ksj->ksi", Binv, dk)
    min_eig = float(values[0]) if values.size else np.inf
    return Stability(
        stable=bool(min_eig > 0 and not conjugate),
        min_eigenvalue=min_eig,
        eigenvalues=values,
        conjugate_segments=conjugate,
        asymmetry=asymmetry,
        modes=modes,
        perturbations=dY / y_scale,
    )


@dataclasses.dataclass(frozen=True, eq=False)
class CriticalPoint:
    """Where a path of equilibria lost its stability: a fold of the path, or a bifurcation.

    between: the path parameter (a grasp's closing, mm) of the last stable equilibrium and
        where the path went on (or tried to).
    min_eigenvalue: the smallest eigenvalue of the tangent stiffness where the search for
        stable equilibria started: the unstable equilibrium past the point (negative), or
        at a fold, which no solve passed, the last stable one (near 0).
    switched: whether the path went on, on a stable branch next to it.
    normal_forces: the normal force on the objects of every stable equilibrium found
        there (the one the path took first); a second value means another stable branch
        exists at that point.
    """

    between: tuple[float, float]
    min_eigenvalue: float
    switched: bool
    normal_forces: tuple[float, ...]

    def describe(self) -> str:
        a, b = self.between
        head = (
            f"stability lost between {a:.4g} and {b:.4g} (smallest eigenvalue "
            f"{self.min_eigenvalue:.3g} where it was tested)"
        )
        if not self.switched:
            return head + ": no stable equilibrium next to it"
        forces = ", ".join(f"{f:.4g} N" for f in self.normal_forces)
        other = "; another stable branch exists" if len(self.normal_forces) > 1 else ""
        return f"{head}: went on on a stable branch (normal forces {forces}){other}"


AMPLITUDES = (0.003, 0.01, 0.03, 0.1, 0.2, 0.3)  # of a mode scaled to 1 (L, 1 rad)


def stable_neighbours(solve, test, unknowns, stab: Stability, amplitudes=AMPLITUDES):
    """Stable equilibria next to an unstable one: Newton started from it displaced along
    its softest mode, each way, by growing amplitudes (the first that converges to a
    stable equilibrium, per side). solve(guess) -> (solution, ok); test(solution) -> its
    Stability. Returns [(solution, Stability)], distinct ones only."""
    found = []
    for side in (1.0, -1.0):
        for a in amplitudes:
            sol, ok = solve(unknowns + side * a * stab.perturbations[0])
            if not ok:
                continue
            s = test(sol)
            if s.stable:
                if all(
                    np.max(np.abs(np.asarray(sol.unknowns) - np.asarray(o.unknowns))) > 1e-6
                    for o, _ in found
                ):
                    found.append((sol, s))
                break
    return found
