"""Banded LU with partial pivoting for the sparse shooting Jacobian.

Every residual row of the shooting problem reads one, two or three segments' states (a
base condition, a cut's continuity, a crossbeam's wrench jump), so the Jacobian is block
sparse. Renumbering the segments by reverse Cuthill-McKee on their coupling graph, and
sorting the rows by their first column, makes it banded: lower bandwidth kl and upper ku
of a dozen or a few dozen on a fin-ray finger, however many segments it has (the graph is
a ladder). LU with partial pivoting keeps a banded matrix banded (fill only up to kl + ku
above the diagonal), so the factorisation is a sequence of small dense steps along the
diagonal instead of one dense LU: about n kl (kl + ku) instead of n^3 / 3 operations.

The pattern is derived from the topology (static, no numbers), so the plan is made once
per topology and reused by every solve, batch member and design.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax import lax
from scipy.sparse.csgraph import reverse_cuthill_mckee


@dataclasses.dataclass(frozen=True, eq=False)
class BandPlan:
    """Row and column order that makes a pattern banded, and the step size of the LU.

    rows, cols: permutations; the banded matrix is J[rows][:, cols].
    kl, ku: lower and upper bandwidth of the permuted pattern.
    block: columns eliminated per step.
    sign: the sign that the two permutations give det (det J = sign det J_perm).
    """

    rows: np.ndarray
    cols: np.ndarray
    kl: int
    ku: int
    block: int
    sign: float
    colors: np.ndarray  # (n, n_colors) 0/1 seeds: columns of one colour share no row
    entries: tuple  # (row, colour, i, j): J[row, col] = (J seeds)[row, colour] -> A[i, j]

    @property
    def n_colors(self):
        return self.colors.shape[1]

    @property
    def n(self):
        return self.rows.shape[0]


def _parity(perm):
    """+1 or -1: the sign of a permutation (by counting cycles)."""
    perm = np.asarray(perm)
    seen = np.zeros(perm.shape[0], bool)
    swaps = 0
    for i in range(perm.shape[0]):
        length = 0
        while not seen[i]:
            seen[i] = True
            i = perm[i]
            length += 1
        swaps += max(length - 1, 0)
    return -1.0 if swaps % 2 else 1.0


def plan_band(row_blocks, block_size: int, n_blocks: int, step_blocks: int = 0) -> BandPlan:
    """Banded ordering of a block-sparse square matrix.

    row_blocks: for each scalar row, the unknown blocks (of `block_size` columns) it reads.
    step_blocks: unknown blocks eliminated per LU step (0: chosen from the bandwidth).
    """
    n = block_size * n_blocks
    if len(row_blocks) != n:
        raise ValueError(f"plan_band: {len(row_blocks)} rows for {n} unknowns")
    graph = np.eye(n_blocks, dtype=bool)
    for deps in row_blocks:
        d = np.asarray(sorted(deps))
        graph[np.ix_(d, d)] = True
    order = np.asarray(reverse_cuthill_mckee(sp.csr_matrix(graph), symmetric_mode=True))
    new_block = np.empty(n_blocks, np.int64)
    new_block[order] = np.arange(n_blocks)
    cols = (order[:, None] * block_size + np.arange(block_size)).reshape(-1)
    lo = np.asarray([block_size * min(new_block[b] for b in deps) for deps in row_blocks])
    hi = np.asarray([block_size * (max(new_block[b] for b in deps) + 1) - 1 for deps in row_blocks])
    rows = np.lexsort((hi, lo))
    i = np.arange(n)
    kl = int(np.max(i - lo[rows]))
    ku = int(np.max(hi[rows] - i))
    if step_blocks <= 0:  # a step about as wide as the band below the diagonal
        step_blocks = max(1, -(-kl // block_size))

    # Colour the blocks greedily (in band order) so that no row reads two blocks of one
    # colour: the Jacobian is then recovered from one directional derivative per colour
    # and block column instead of one per unknown.
    block_color = np.full(n_blocks, -1)
    for b in order:
        taken = set(block_color[graph[b]])
        block_color[b] = next(c for c in range(n_blocks) if c not in taken)
    k = np.arange(block_size)
    color = (block_color[:, None] * block_size + k).reshape(-1)  # per original column
    seeds = np.zeros((n, int(color.max()) + 1))
    seeds[np.arange(n), color] = 1.0
    inv_rows = np.empty(n, np.int64)
    inv_rows[rows] = np.arange(n)
    inv_cols = np.empty(n, np.int64)
    inv_cols[cols] = np.arange(n)
    src_row, src_color, dst_i, dst_j = [], [], [], []
    for r, deps in enumerate(row_blocks):
        for b in sorted(deps):
            c = b * block_size + k
            src_row += [r] * block_size
            src_color += list(color[c])
            dst_i += [inv_rows[r]] * block_size
            dst_j += list(inv_cols[c])
    entries = tuple(np.asarray(a, np.int64) for a in (src_row, src_color, dst_i, dst_j))
    sign = _parity(rows) * _parity(cols)
    return BandPlan(rows, cols, kl, ku, step_blocks * block_size, sign, seeds, entries)


def covers(plan: BandPlan, J) -> bool:
    """Whether every non-zero of J lies inside the plan's band (a test of the pattern)."""
    A = np.asarray(J)[plan.rows][:, plan.cols]
    i, j = np.nonzero(A)
    return bool(np.all(i - j <= plan.kl) and np.all(j - i <= plan.ku))


class BandLU(eqx.Module):
    """Factors of a banded matrix: L and U stored in place (padded), per-step row orders."""

    lu: jax.Array  # (P, P)
    perms: jax.Array  # (steps, h): row order applied at each step
    sign: jax.Array  # sign of det of the (unpermuted) matrix


def _sizes(plan: BandPlan):
    nb = plan.block
    steps = -(-plan.n // nb)
    h = nb + plan.kl  # rows that can hold a pivot for a step's columns
    w = nb + plan.kl + plan.ku  # columns a step's rows can reach after fill
    return nb, steps, h, w, steps * nb + plan.kl + plan.ku


def seeded(plan: BandPlan, jvp, dtype):
    """J S (n, n_colors): a linear map `jvp` (J times a vector) applied to the colour
    seeds, batched."""
    return jax.vmap(jvp, in_axes=1, out_axes=1)(jnp.asarray(plan.colors, dtype))


def compressed(plan: BandPlan, fn, y):
    """fn(y) and J S (n, n_colors): the Jacobian times the colour seeds, one forward pass
    with `n_colors` tangents."""
    r, jvp = jax.linearize(fn, y)
    return r, seeded(plan, jvp, y.dtype)


def linearize(plan: BandPlan, fn, y):
    """fn(y) and its Jacobian, padded and permuted into band order (P, P)."""
    r, JS = compressed(plan, fn, y)
    return r, band(plan, JS)


def dense(plan: BandPlan, JS):
    """The Jacobian (n, n), in the original order, from its compressed form."""
    src_row, src_color, _, dst_j = plan.entries
    J = jnp.zeros((plan.n, plan.n), JS.dtype)
    return J.at[src_row, plan.cols[dst_j]].set(JS[src_row, src_color])


def band(plan: BandPlan, JS):
    """The padded band-ordered matrix (P, P) from the compressed Jacobian."""
    return _banded_matrix(plan, JS[plan.entries[0], plan.entries[1]])


def _banded_matrix(plan: BandPlan, values):
    _, _, _, _, P = _sizes(plan)
    n = plan.n
    pad = jnp.arange(n, P)
    A = jnp.zeros((P, P), values.dtype).at[pad, pad].set(1.0)
    return A.at[plan.entries[2], plan.entries[3]].set(values)


def _panel_lapack(W, nb: int):
    """Gaussian elimination with partial pivoting of the first nb columns of W (h, w):
    returns W with L (unit, below the diagonal) and U of those columns in place and the
    rest of the rows updated (U12 on top, the Schur complement below), the row order
    applied (W_in[perm]) and the sign of the pivots times that of the permutation.
    The panel's LU by LAPACK (`lax.linalg.lu`), then a triangular solve and a product."""
    lu, pivots, perm = lax.linalg.lu(W[:, :nb])
    W = W[perm]
    L11 = jnp.tril(lu[:nb], -1) + jnp.eye(nb, dtype=W.dtype)
    U12 = jax.scipy.linalg.solve_triangular(L11, W[:nb, nb:], lower=True, unit_diagonal=True)
    W22 = W[nb:, nb:] - lu[nb:] @ U12
    W = jnp.concatenate(
        [jnp.concatenate([lu[:nb], U12], axis=1), jnp.concatenate([lu[nb:], W22], axis=1)]
    )
    swaps = jnp.sum(pivots != jnp.arange(nb, dtype=pivots.dtype))
    flip = jnp.where(swaps % 2 == 0, 1.0, -1.0).astype(W.dtype)
    return W, perm, jnp.prod(jnp.sign(jnp.diagonal(lu[:nb]))) * flip


def _panel_elementwise(W, nb: int):
    """As `_panel_lapack`, one column at a time with element-wise updates and row swaps by
    selection (the arithmetic of LAPACK's unblocked getf2).

    On a GPU, jax factorises a vmapped batch of non-square matrices one matrix after
    another (a cuSOLVER call each); this is a few fused kernels for the whole batch. On a
    CPU, LAPACK's panel is faster than this, so `_panel` picks by platform (the
    figures for both: benchmarks/README.md).
    """
    h = W.shape[0]
    rows = jnp.arange(h)
    perm = rows
    sign = jnp.ones((), W.dtype)
    for j in range(nb):
        p = jnp.argmax(jnp.where(rows >= j, jnp.abs(W[:, j]), -1.0))
        row_j, row_p = W[j], W[p]
        W = jnp.where((rows == j)[:, None], row_p, jnp.where((rows == p)[:, None], row_j, W))
        perm = jnp.where(rows == j, perm[p], jnp.where(rows == p, perm[j], perm))
        piv = W[j, j]
        sign = sign * jnp.where(p == j, 1.0, -1.0) * jnp.sign(piv)
        # (a zero pivot heads a zero column: it is left as it is, as getf2 does)
        col = W[j + 1 :, j] / jnp.where(piv == 0.0, 1.0, piv)
        W = W.at[j + 1 :, j].set(col)
        W = W.at[j + 1 :, j + 1 :].add(-col[:, None] * W[j, j + 1 :][None, :])
    return W, perm.astype(jnp.int32), sign


def _panel(W, nb: int):
    """The LU step of `factor` on W (h, w): LAPACK on a CPU, element-wise elsewhere."""
    return lax.platform_dependent(
        W,
        cpu=functools.partial(_panel_lapack, nb=nb),
        default=functools.partial(_panel_elementwise, nb=nb),
    )


def factor(plan: BandPlan, Ap) -> BandLU:
    """LU with partial pivoting of the padded band-ordered matrix Ap (from `linearize` or
    `pad`), eliminating `block` columns per step within the band."""
    nb, steps, h, w, _ = _sizes(plan)
    dtype = Ap.dtype

    def step(k, carry):
        Ap, perms, sign = carry
        c0 = k * nb
        W, perm, s = _panel(lax.dynamic_slice(Ap, (c0, c0), (h, w)), nb)
        return lax.dynamic_update_slice(Ap, W, (c0, c0)), perms.at[k].set(perm), sign * s

    init = (Ap, jnp.zeros((steps, h), jnp.int32), jnp.asarray(plan.sign, dtype))
    Ap, perms, sign = lax.fori_loop(0, steps, step, init)
    return BandLU(Ap, perms, sign)


def lu_shape(plan: BandPlan) -> tuple[int, int]:
    """The shape of `BandLU.lu` for this plan (padded, P x P)."""
    P = _sizes(plan)[-1]
    return (P, P)


def no_factors(plan: BandPlan, dtype) -> BandLU:
    """Zero factors of `factor`'s shapes (a loop's initial carry; no trace of a factor)."""
    _, steps, h, _, _ = _sizes(plan)
    return BandLU(
        jnp.zeros(lu_shape(plan), dtype), jnp.zeros((steps, h), jnp.int32), jnp.zeros((), dtype)
    )


def solve(plan: BandPlan, fac: BandLU, b):
    """x with A x = b for the factored A."""
    nb, steps, h, w, P = _sizes(plan)
    n = plan.n
    bp = jnp.concatenate([b, jnp.zeros(P - n, b.dtype)])  # (gathers and slices only:
    # the solve is transposed when reverse mode differentiates through it)

    def forward(k, bp):
        c0 = k * nb
        seg = lax.dynamic_slice(bp, (c0,), (h,))[fac.perms[k]]
        L = lax.dynamic_slice(fac.lu, (c0, c0), (h, nb))
        y1 = jax.scipy.linalg.solve_triangular(L[:nb], seg[:nb], lower=True, unit_diagonal=True)
        return lax.dynamic_update_slice(bp, jnp.concatenate([y1, seg[nb:] - L[nb:] @ y1]), (c0,))

    def backward(j, x):
        c0 = (steps - 1 - j) * nb
        U = lax.dynamic_slice(fac.lu, (c0, c0), (nb, w))
        rhs = lax.dynamic_slice(bp, (c0,), (nb,)) - U[:, nb:] @ lax.dynamic_slice(
            x, (c0 + nb,), (w - nb,)
        )
        xb = jax.scipy.linalg.solve_triangular(U[:, :nb], rhs, lower=False)
        return lax.dynamic_update_slice(x, xb, (c0,))

    bp = lax.fori_loop(0, steps, forward, bp)
    x = lax.fori_loop(0, steps, backward, jnp.zeros(P, b.dtype))  # c0 + w <= P
    return x[:n]


def pad(plan: BandPlan, J):
    """A dense J (n, n) in padded band order."""
    return _banded_matrix(plan, J[plan.entries[0], plan.cols[plan.entries[3]]])


def solve_factored(plan: BandPlan, fac: BandLU, r):
    """x with J x = r, J factored by `factor` (in band order)."""
    z = solve(plan, fac, r[plan.rows])
    return z[np.argsort(plan.cols)]
