"""The segment flow: every segment's end state from its start state and parameters.

The segment flow has a custom JVP: each segment's own small Jacobian (state and parameter
columns) is computed once per evaluation by forward mode, and tangents are pushed through
it with a matrix product. Newton's Jacobian then costs one batched forward pass instead of
one re-integration per unknown, and reverse mode works because the rule is linear in the
tangents. Only the start state's own directions are integrated: a 3-D frame turns in three
ways (not nine matrix entries), and without contact a translation of the start translates
the end (no integration needed): 4 of 6 directions planar, 9 of 18 in 3-D.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._integrator import integrate


def segment_trajectories(model, integrator, Y0, Q):
    """States at the n+1 step points of every segment: (S, steps + 1, n_full).

    The first point is the state after the rigid part (the clamp exit), which equals the
    start for a segment without a rigid part.
    """
    return jax.vmap(lambda y, q: integrate(model, integrator, y, q, True))(Y0, Q)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def segment_flow(model, integrator, Y0, Q):
    """End states of all segments: (S, n_full)."""
    return jax.vmap(lambda y, q: integrate(model, integrator, y, q, False))(Y0, Q)


def flow_jacobians(
    model,
    integrator,
    Y0,
    Q,
    need_y=True,
    need_q=True,
    save_all=False,
    q_columns=None,
    merge_rigid=True,
):
    """Integrate every segment with the Jacobians of its output (the end state, or with
    `save_all` the states at every step point) with respect to the start state's own
    tangent coordinates (`tangent_coords`) and to the parameters: one forward pass with
    those directions. q_columns: the parameter columns to differentiate in (static; None:
    all of them). Returns (out, jac_y, jac_q); a Jacobian not asked for is None.

    Columns 0 (length) and 1 (rigid) share one integrated direction: the flow reads them
    only as the flexible length, length - rigid, and as the rigid transport at the start,
    whose derivative is the start-state tangent `rigid_start_tangent`. So d/d rigid is
    minus d/d length plus the state Jacobian applied to that tangent, one integrated
    direction fewer (the pass costs by the number of directions, in steps of four).
    merge_rigid=False integrates both directions (for comparison)."""
    cols = None if q_columns is None else np.asarray(q_columns)
    merge = merge_rigid and need_q and cols is not None and 0 in cols and 1 in cols
    integrated = cols[cols != 1] if merge else cols

    def one(y, q):
        # Differentiate along the start state's own tangent directions only (a frame
        # turns in 3 ways, not 9; translations need no integration without contact).
        E = model.tangent_basis(y)
        if integrated is None:
            b0, full = q, lambda b: b
        else:
            b0, full = q[integrated], lambda b: q.at[integrated].set(b)

        def twice(d, b):
            o = integrate(model, integrator, y + E @ d, full(b), save_all)
            return o, o

        d0 = jnp.zeros(E.shape[1], y.dtype)
        return jax.jacfwd(twice, argnums=argnums, has_aux=True)(d0, b0)

    with_y = need_y or merge
    argnums = tuple(i for i, need in ((0, with_y), (1, need_q)) if need)
    jacs, out = jax.vmap(one)(Y0, Q)
    jac_y = jacs[0] if with_y else None
    jac_q = jacs[-1] if need_q else None
    if merge:
        dY0 = jax.vmap(model.rigid_start_tangent)(Y0, Q)
        rigid = apply_flow_jacobians(model, Y0, dY0, None, jac_y, None)
        length = int(np.flatnonzero(integrated == 0)[0])
        rigid = rigid - jac_q[..., length]
        at = int(np.flatnonzero(cols == 1)[0])
        jac_q = jnp.concatenate([jac_q[..., :at], rigid[..., None], jac_q[..., at:]], axis=-1)
    return out, (jac_y if need_y else None), jac_q


def apply_flow_jacobians(model, Y0, dY0, dQ, jac_y, jac_q, q_columns=None):
    """The tangent of `flow_jacobians`' output for start-state and parameter tangents
    dY0, dQ (either may be None; dQ's columns outside `q_columns`, those `jac_q` is
    taken in, must be zero): linear in them, so reverse mode transposes it."""
    like = jac_y if jac_y is not None else jac_q
    shape = like.shape[:-1]
    dout = jnp.zeros(shape, like.dtype)
    if dY0 is not None:
        d = jax.vmap(model.tangent_coords)(Y0, dY0)
        dout = dout + jnp.einsum("s...j,sj->s...", jac_y, d)
        if model.translation_free:  # a start translation moves every point alike
            pos = model.position_slice
            shift = dY0[:, pos].reshape((shape[0],) + (1,) * (len(shape) - 2) + (-1,))
            dout = dout.at[..., pos].add(shift)
    if dQ is not None:
        dQ = dQ if q_columns is None else dQ[:, np.asarray(q_columns)]
        dout = dout + jnp.einsum("s...j,sj->s...", jac_q, dQ)
    return dout


def _segment_flow_jvp(model, integrator, primals, tangents):
    Y0, Q = primals
    dY0, dQ = tangents
    zero = jax.custom_derivatives.SymbolicZero
    need_y, need_q = not isinstance(dY0, zero), not isinstance(dQ, zero)
    if not (need_y or need_q):
        out = segment_flow(model, integrator, Y0, Q)
        return out, jnp.zeros_like(out)
    out, jac_y, jac_q = flow_jacobians(model, integrator, Y0, Q, need_y, need_q)
    dout = apply_flow_jacobians(
        model, Y0, dY0 if need_y else None, dQ if need_q else None, jac_y, jac_q
    )
    return out, dout


segment_flow.defjvp(_segment_flow_jvp, symbolic_zeros=True)
