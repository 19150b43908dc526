"""Contact outputs of a solved finger: the objects' and the support's forces, pressures,
penetrations and contact length, the crossbeams' force on the front beam, the actuator's
force, and the members' contact on each other.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ._contact import (
    penalty,
    smoothing,
    stiffness,
    support_smoothing,
    support_stiffness,
)
from ._finger import BACK, FRONT, DistributedLoad, Finger
from ._geometry import geometry, thickness_at
from ._members import group_forces
from ._objects import safe_norm
from ._solution import Solution
from ._solve import make_problem
from ._types import as_float


class ContactResult(eqx.Module):
    """Contact outputs of one equilibrium (one finger).

    force: total force (x, y, z) the objects exert on the finger (N).
    normal_force: integral of the normal contact pressure over the beams (N).
    pressure_front, pressure_back: normal contact force per unit length (N/mm) at the
        points of the front and back beams' solutions (`Solution.front.s`, `.back.s`).
    contact_length: arc length in contact (penetration > 0), both beams (mm).
    max_penetration: largest penetration of a beam's surface into an object (mm).
    support_penetration: largest penetration of the back beam into the support (mm).
    support_force: total force of the adaptor's support on the back beam (N).
    crossbeam_force: mean force the crossbeams apply to the front beam (x, y, z) (N): the
        paper's Fig. 4 metric.
    actuator_force: force along the closing direction the actuator applies to the
        finger's adaptor (N): everything the adaptor applies to the finger (base reactions
        and the support) projected on the closing direction.
    member_penetration: largest penetration of one member of the finger into another
        (mm; 0 where member contact is off, `Contact.member_contact`).
    member_force: (members, members) the contact force member j presses on member i
        with (N; members are front, back, then the crossbeams); internal, so it is in no
        balance of the finger as a whole.
    """

    force: jax.Array
    normal_force: jax.Array
    pressure_front: jax.Array
    pressure_back: jax.Array
    contact_length: jax.Array
    max_penetration: jax.Array
    support_penetration: jax.Array
    support_force: jax.Array
    crossbeam_force: jax.Array
    actuator_force: jax.Array
    member_penetration: jax.Array = eqx.field(converter=as_float, default=0.0)
    member_force: jax.Array = eqx.field(converter=as_float, default=((0.0,),))


@functools.partial(jax.jit, static_argnums=(0, 1))
def _member_outputs(topo, integrator, finger, Y, lam):
    """(largest penetration, (B, B) contact forces) between the finger's members."""
    problem = make_problem(topo, integrator, finger)
    starts, ends = problem.ends(jnp.reshape(Y, (topo.n_segments, -1)), lam)
    plan = topo.members
    size, gap = group_forces(plan, *problem.member_args(starts, ends))
    pen = jnp.max(jnp.maximum(-gap, 0.0), initial=0.0)
    a, b = plan.group_members[:, 0], plan.group_members[:, 1]
    B = topo.n_beams
    # every group's force acts on its sample's member (a) and back on the other (b)
    forces = jnp.zeros((B, B)).at[a, b].add(size).at[b, a].add(size)
    return pen, 0.5 * forces


def with_members(res: ContactResult, topo, integrator, finger, sol) -> ContactResult:
    """The contact result with the members' contact filled in (from the topology)."""
    if topo.members is None or not topo.members.n_groups:
        return res
    pen, forces = _member_outputs(topo, integrator, finger, sol.unknowns, sol.load_factor)
    return dataclasses.replace(res, member_penetration=pen, member_force=forces)


@eqx.filter_jit
def contact_result(finger: Finger, sol: Solution, direction) -> ContactResult:
    """Contact outputs of a solved finger (objects, support, crossbeams, reactions).

    Totals are exact for the discrete model: on every segment the contact force is the
    change of the internal force n that the distributed loads do not explain (n' = -f).
    Sampled pressures at the solution points split it between objects and support and
    give the normal force.
    """
    geo = geometry(finger)
    penalties = (stiffness(finger), smoothing(finger))
    clamp = (finger.adaptor.front_clamp_length, finger.adaptor.back_clamp_length)
    force = jnp.zeros(3)
    support = jnp.zeros(3)
    normal = jnp.zeros(())
    length = jnp.zeros(())
    pen = jnp.zeros(())
    sup_pen = jnp.zeros(())
    pressures = []
    w = jnp.insert(as_float(direction), 1, 0.0)
    for beam, bs in ((FRONT, sol.front), (BACK, sol.back)):
        p = bs.position[:, ::2]
        h = 0.5 * thickness_at(
            finger.front if beam == FRONT else finger.back, bs.s, geo.length[beam]
        )
        free = bs.s > clamp[beam]  # no contact inside a clamp
        f_obj, q_obj, pen, length = _objects_on_beam(finger, penalties, bs, p, h, free, pen, length)
        f_sup, backed, sup_pen = _support_on_beam(
            finger, geo, beam, bs, p, free, sol.steps, sup_pen
        )
        obj_part, exact, q_exact = _split_segment_forces(
            finger, beam, bs, sol.steps, f_obj, f_sup, q_obj, backed
        )
        force = force + jnp.insert(jnp.sum(obj_part, axis=0), 1, 0.0)
        support = support + jnp.insert(jnp.sum(exact - obj_part, axis=0), 1, 0.0)
        normal = normal + jnp.sum(q_exact)
        pressures.append(q_obj)
    reactions = sol.reactions_front.force + sol.reactions_back.force + support
    cb = sol.crossbeam_wrenches.front_force
    return ContactResult(
        force=force,
        normal_force=normal,
        pressure_front=pressures[0],
        pressure_back=pressures[1],
        contact_length=length,
        max_penetration=pen,
        support_penetration=sup_pen,
        support_force=support,
        crossbeam_force=jnp.mean(cb, axis=0) if cb.shape[0] else jnp.zeros(3),
        actuator_force=jnp.dot(reactions, w),
    )


def _objects_on_beam(finger, penalties, bs, p, h, free, pen, length):
    """The objects' sampled contact on one beam, at its solution points: (force per length
    (x, z), normal pressure, the running largest penetration, the running contact length)
    (`pen` and `length`: their values over the beams and objects before this one)."""
    c = finger.contact
    k, delta = penalties
    q_obj = jnp.zeros_like(bs.s)  # normal pressure from objects
    f_obj = jnp.zeros((bs.s.shape[0], 2))  # force per length from objects
    for obj in finger.objects:
        q = obj.params()
        d, nx, nz = jax.vmap(obj.distance_and_normal, in_axes=(None, 0, 0))(q, p[:, 0], p[:, 1])
        grad = jnp.stack([nx, nz], axis=-1)
        gap = d - h
        qn = jnp.where(free, penalty(gap, k, delta), 0.0)
        t = bs.frame[:, ::2, 2]
        slide = c.friction * jnp.tanh((t @ c.slip_direction) / c.friction_regularisation)
        f_obj = f_obj + qn[:, None] * (grad + slide[:, None] * t)
        q_obj = q_obj + qn
        pen = jnp.maximum(pen, jnp.max(jnp.where(free, -gap, 0.0)))
        length = length + _length_inside(jnp.where(free, gap, 1.0), bs.s)
    return f_obj, q_obj, pen, length


def _support_on_beam(finger, geo, beam, bs, p, free, steps, sup_pen):
    """The support's sampled contact on one beam (the back beam, when the adaptor has a
    support; none on the front beam): (force per length (x, z), which segments it backs,
    its penetration (`sup_pen` where it does not act))."""
    f_sup = jnp.zeros((bs.s.shape[0], 2))
    backed = jnp.zeros(bs.s.shape[0] // (steps + 2), bool)  # segments the support backs
    if beam == BACK and finger.adaptor.support_length is not None:
        k_s, delta_s = support_stiffness(finger), support_smoothing(finger)
        th = geo.theta[BACK]
        nrm = -jnp.stack([jnp.cos(th), -jnp.sin(th)])
        gap = (p - geo.base[BACK, ::2]) @ nrm
        # The support acts on whole segments (those that end at or before l_s), so its
        # force at s = l_s, where a stiff penalty concentrates it, belongs to it too.
        ends = _blocks(bs.s, steps)[:, -1]
        backed = ends <= finger.adaptor.support_length * (1.0 + 1e-12)
        on = free & jnp.repeat(backed, steps + 2)
        f_sup = jnp.where(on, penalty(gap, k_s, delta_s), 0.0)[:, None] * nrm[None]
        sup_pen = jnp.max(jnp.where(on, -gap, 0.0))
    return f_sup, backed, sup_pen


def _split_segment_forces(finger, beam, bs, steps, f_obj, f_sup, q_obj, backed):
    """Each segment's exact contact force (from the jump of n, less the distributed
    loads), split between the objects and the support by the sampled forces: (the objects'
    part (x, z), the exact total (x, z), the objects' normal force), one row a segment."""
    s_b = _blocks(bs.s, steps)
    n_b = _blocks(bs.force[:, ::2], steps)
    dist = _distributed(finger, beam, s_b[:, 0], s_b[:, -1])
    exact = -(n_b[:, -1] - n_b[:, 0]) - dist
    so, ss, qo = (_blocks_integral(x, s_b, steps) for x in (f_obj, f_sup, q_obj[:, None]))
    sampled = so + ss
    # (the floor keeps tiny a normal number, and the division never sees 0 / 0 even
    # in the unselected branch, so reverse-mode gradients stay finite)
    tiny = 1e-24 * jnp.maximum(jnp.sum(exact * exact, axis=1), 1e-280)
    size = jnp.sum(sampled * sampled, axis=1)
    has_o = jnp.sum(so * so, axis=1) > tiny
    has_s = jnp.sum(ss * ss, axis=1) > tiny
    some = size > tiny
    scale = jnp.where(some, jnp.sum(exact * sampled, axis=1) / jnp.where(some, size, 1.0), 1.0)
    # All of the segment's contact force goes to what touches it; if both do, split
    # by the sampled shares. A contact too concentrated for the solution's points
    # (a stiff support's edge force acts between them) is the support's on the
    # segments it backs where no object is seen.
    to_objects = ~has_s & (has_o | ~backed)
    obj_part = jnp.where(
        to_objects[:, None],
        exact,
        jnp.where((has_o & has_s)[:, None], scale[:, None] * so, 0.0),
    )
    q_exact = jnp.where(has_o & some, scale * qo[:, 0], safe_norm(obj_part))
    return obj_part, exact, q_exact


def _blocks(x, steps):
    """The per-point rows of x, one block of steps + 2 rows a segment."""
    return x.reshape((-1, steps + 2) + x.shape[1:])


def _length_inside(gap, s):
    """Arc length where gap < 0, with zero crossings interpolated linearly."""
    g0, g1 = gap[:-1], gap[1:]
    ds = s[1:] - s[:-1]
    both = (g0 < 0) & (g1 < 0)
    one = (g0 < 0) != (g1 < 0)
    span = jnp.where(one, jnp.abs(g0 - g1), 1.0)
    frac = jnp.where(one, -jnp.minimum(g0, g1) / span, 0.0)
    return jnp.sum(jnp.where(both, ds, frac * ds))


def _blocks_integral(x, s_b, steps):
    """Trapezoid integral of x over every segment block: (segments, columns)."""
    x_b = _blocks(x, steps)
    ds = (s_b[:, 1:] - s_b[:, :-1])[..., None]
    return jnp.sum(0.5 * (x_b[:, 1:] + x_b[:, :-1]) * ds, axis=1)


def _distributed(finger: Finger, beam: int, s0, s1):
    """Resultant (x, z) of the distributed loads on each segment [s0, s1] of a beam."""
    total = jnp.zeros((s0.shape[0], 2))
    for ld in finger.loads:
        if isinstance(ld, DistributedLoad) and ld.beam == beam:
            a, b = ld.s_range[0], ld.s_range[1]
            overlap = jnp.clip(jnp.minimum(s1, b) - jnp.maximum(s0, a), 0.0, None)
            total = total + overlap[:, None] * ld.force_per_length[::2][None]
    return total
