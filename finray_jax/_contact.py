"""Penalty contact between the main beams and rigid objects, and the adaptor's support.

A beam is a band of half-thickness h around its centreline p(s). Its gap to an object is
g = d(p) - h, with d the object's signed distance, so the band's surface touches the
object at g = 0 (exact for either face of the band). The object pushes the beam along the
distance gradient (the outward normal) with a force per unit length q = k ramp(-g), where
the ramp is zero for no penetration, quadratic over the first delta of penetration and
linear beyond (continuously differentiable: no kink for Newton, and no force at all
before touching). Penetration therefore equals delta / 2 + q / k once q > k delta / 2.
With friction coefficient mu the object also drags the beam along the beam's tangent t
with mu q tanh((w . t) / eps), w being the unit direction in which the object moves
relative to the finger (the slip direction): a regularised Coulomb law for a sliding
contact. The friction force acts at the band's surface and so also applies a moment per
length about the centreline.

The adaptor's rigid support behind the back beam is a line through the back beam's base
along its undeformed tangent, acting over s in [0, l_s]: it pushes the back beam forward
(toward the front beam) by the same law, with its own stiffness and smoothing, the gap
measured as the back beam's displacement toward the support, and never pulls it. The
back beam meets the support's end as an edge: its force concentrates at s = l_s, and its
penetration there falls more slowly with k than a distributed contact's (about k^-3/4 for
a beam on an elastic bed instead of 1/k), so the support has its own penetration limit.

All contact enters the rod equations as a distributed load n' = -f, m' = -p' x n - l, so
it is solved inside the equilibrium, and is smooth in every state and design value.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import FingerError
from ._objects import kind_by_key, param_size
from ._types import as_float

N_SEGMENT = 4  # per-segment contact columns: object flag, support flag, h at start, h at end
N_GLOBAL = 12  # k, delta, mu, eps, slip (2), support point (2), support normal (2), k_s, delta_s


class Contact(eqx.Module):
    """How contact is modelled (penalty law, friction, resolution).

    stiffness: k, contact force per unit length per mm of penetration (N/mm^2). None:
        chosen from the finger, E depth / thickness of the front beam.
    max_penetration: the allowed penetration as a fraction of the front beam's thickness
        (default 0.02). The smoothing is delta = max_penetration * thickness / 2, and
        `grasp` stiffens k until the largest penetration stays below the limit.
    support_stiffness: the support's k (N/mm^2). None: the same as `stiffness`.
    max_support_penetration: the support's allowed penetration as a fraction of the back
        beam's thickness. None: the same fraction as `max_penetration`. Its smoothing is
        max_support_penetration * thickness / 2, and `grasp` stiffens the support until
        the back beam's penetration into it stays below the limit.
    friction: Coulomb coefficient mu (0: frictionless).
    friction_regularisation: eps of tanh((w . t) / eps) (dimensionless; the slip
        direction w and the tangent t are unit vectors).
    slip_direction: w, the unit direction (x, z) in which the object slides relative to
        the finger (friction acts only with a non-zero w; `release_force` sets it).
    segment_length: main beams are cut into shooting segments no longer than this (mm),
        so that the fixed-step integration resolves the contact (static).
    near_segments: a Newton solve at full load evaluates the contact law on this many
        main-beam segments besides those the support backs (static): the ones nearest
        the objects and the support where it starts. Elsewhere the rhs has no contact
        terms, which makes an iteration about twice as fast (the contact law and the two
        position directions it adds to every segment's Jacobian). The solve checks the
        choice (the other segments' start points at every iterate, all their step points
        at a root): where one of them touches, it chooses again from that state and goes
        on, up to three choices, and otherwise reports `contact_outside_near_segments`
        (the path solver of `grasp` and `release_force` then goes on with every segment).
        None: every segment, always.
    member_contact: contact between the finger's own members (crossbeams, front and back
        beam; see `_members`), static. None: on for fingers with objects or a support
        (their crossbeams are then cut into equal pieces no longer than twice
        `segment_length`); True: always; False: never.
    member_stiffness: the members' k (N/mm^2). None: the same as `stiffness`.
    max_member_penetration: the members' allowed penetration into each other as a
        fraction of the thinnest member's thickness. None: the same fraction as
        `max_penetration`. Its smoothing is half that penetration, and `grasp` stiffens
        the members' contact until it holds.
    member_reach: members farther apart than this in the undeformed finger (mm, gap
        between their surfaces) are not tested against each other (static).
    """

    stiffness: jax.Array | None = eqx.field(
        converter=lambda x: None if x is None else as_float(x), default=None
    )
    max_penetration: jax.Array = eqx.field(converter=as_float, default=0.02)
    support_stiffness: jax.Array | None = eqx.field(
        converter=lambda x: None if x is None else as_float(x), default=None
    )
    max_support_penetration: jax.Array | None = eqx.field(
        converter=lambda x: None if x is None else as_float(x), default=None
    )
    friction: jax.Array = eqx.field(converter=as_float, default=0.0)
    friction_regularisation: jax.Array = eqx.field(converter=as_float, default=0.05)
    slip_direction: jax.Array = eqx.field(converter=as_float, default=(0.0, 0.0))
    segment_length: float = eqx.field(static=True, default=5.0)
    near_segments: int | None = eqx.field(static=True, default=8)
    member_contact: bool | None = eqx.field(static=True, default=None)
    member_stiffness: jax.Array | None = eqx.field(
        converter=lambda x: None if x is None else as_float(x), default=None
    )
    max_member_penetration: jax.Array | None = eqx.field(
        converter=lambda x: None if x is None else as_float(x), default=None
    )
    member_reach: float = eqx.field(static=True, default=10.0)


@dataclasses.dataclass(frozen=True)
class ContactSpec:
    """Static layout of the contact parameters: object keys, whether there is a support,
    and whether friction can act.

    near: how many segments (the nearest) a Newton solve at full load evaluates the
    contact law on (`Contact.near_segments` plus the supported segments); None: all.
    friction: False when the finger's friction is known to vanish (mu = 0, or no slip
    direction, as while closing). The rhs then leaves the friction law out, a third of
    the cost of a contact problem's segment Jacobians. A finger whose friction may act
    (concretely non-zero, or traced) needs a topology with friction (`check_friction`).
    """

    objects: tuple = ()
    support: bool = False
    friction: bool = True
    near: int | None = None  # segments a full-load Newton solve evaluates contact on

    @property
    def empty(self) -> bool:
        """No contact law at all (`free`)."""
        return not self.objects and not self.support

    def free(self) -> "ContactSpec":
        """The layout of segments that integrate without contact terms in a contact
        problem (`Problem.order`): their rhs is the contact model's, the law left out."""
        return ContactSpec()

    @property
    def sizes(self):
        return tuple(param_size(k) for k in self.objects)

    @property
    def n_params(self):
        return N_SEGMENT + N_GLOBAL + sum(self.sizes)


def _concrete(x):
    """x as a NumPy array, or None when it is traced (it may then be anything)."""
    try:
        return np.asarray(x)
    except jax.errors.TracerArrayConversionError:
        return None


def _friction_acts(contact: "Contact"):
    """Whether friction acts (mu > 0 and a slip direction): True, False, or None when a
    traced value leaves it open."""
    mu, w = _concrete(contact.friction), _concrete(contact.slip_direction)
    if (mu is not None and not np.any(mu)) or (w is not None and not np.any(w)):
        return False
    return None if mu is None or w is None else True


def friction_may_act(contact: "Contact") -> bool:
    return _friction_acts(contact) is not False


def contact_spec(finger):
    """The static contact layout of a finger (None without objects or support)."""
    support = finger.adaptor.support_length is not None
    if not finger.objects and not support:
        return None
    objects = tuple(o.key() for o in finger.objects)
    return ContactSpec(objects, support, friction_may_act(finger.contact))


def check_friction(spec: ContactSpec | None, finger):
    """Raise when a topology without friction meets a finger whose friction acts. (Under
    a trace, where the friction is not known, the topology is trusted: a traced finger
    with friction needs `with_friction(topology)` or a topology built with friction.)"""
    if spec is None or spec.friction or not _friction_acts(finger.contact):
        return
    c = finger.contact
    raise FingerError(
        "the topology was built for frictionless contact (contact.friction = 0 or no "
        f"slip_direction), but this finger has contact.friction = {np.asarray(c.friction)} "
        f"and contact.slip_direction = {np.asarray(c.slip_direction).tolist()}: pass "
        "finray_jax.with_friction(topology), or finray_jax.topology_of(this finger)"
    )


def with_friction(topology):
    """The same topology with the friction law in the rhs (for fingers whose friction
    may act: concretely non-zero, or traced)."""
    if topology.contact is None or topology.contact.friction:
        return topology
    return dataclasses.replace(
        topology, contact=dataclasses.replace(topology.contact, friction=True)
    )


def penalty(g, k, delta):
    """Contact force per unit length at gap g (negative: penetration): k times a ramp in
    the penetration x = -g that is 0 for x <= 0, x^2 / (2 delta) up to delta, then
    x - delta / 2 (C1)."""
    x = -g
    quad = jnp.clip(x, 0.0, delta)
    return k * (quad * quad / (2.0 * delta) + jnp.maximum(x - delta, 0.0))


def default_stiffness(finger):
    return finger.material.E * finger.front.depth / finger.front.thickness


def smoothing(finger):
    return finger.contact.max_penetration * finger.front.thickness / 2.0


def stiffness(finger):
    """The objects' penalty stiffness k (N/mm^2)."""
    c = finger.contact
    return default_stiffness(finger) if c.stiffness is None else c.stiffness


def support_stiffness(finger):
    """The support's penalty stiffness (N/mm^2)."""
    c = finger.contact
    return stiffness(finger) if c.support_stiffness is None else c.support_stiffness


def support_penetration_limit(finger):
    """The support's largest allowed penetration (mm)."""
    c = finger.contact
    frac = c.max_penetration if c.max_support_penetration is None else c.max_support_penetration
    return frac * finger.back.thickness


def support_smoothing(finger):
    return support_penetration_limit(finger) / 2.0


def members_touch(finger) -> bool:
    """Whether the finger's members are tested for contact with each other."""
    on = finger.contact.member_contact
    if on is None:
        return bool(finger.objects) or finger.adaptor.support_length is not None
    return bool(on)


def member_stiffness(finger):
    """The members' penalty stiffness (N/mm^2)."""
    c = finger.contact
    return stiffness(finger) if c.member_stiffness is None else c.member_stiffness


def penalty_stiffnesses(finger) -> tuple:
    """The three penalty stiffnesses (objects, support, members), in `with_stiffness`'s
    order (N/mm^2)."""
    return stiffness(finger), support_stiffness(finger), member_stiffness(finger)


def member_penetration_limit(finger):
    """The members' largest allowed penetration into each other (mm)."""
    c = finger.contact
    frac = c.max_penetration if c.max_member_penetration is None else c.max_member_penetration
    ends = lambda sec: (
        sec.thickness,
        sec.thickness if sec.tip_thickness is None else sec.tip_thickness,
    )
    thinnest = jnp.min(jnp.stack([*ends(finger.front), *ends(finger.back)]))
    if finger.n_crossbeams:
        thinnest = jnp.minimum(thinnest, jnp.min(finger.crossbeams.thickness))
    return frac * thinnest


def member_smoothing(finger):
    return member_penetration_limit(finger) / 2.0


def global_params(finger, geo):
    """The contact parameter vector shared by every segment."""
    c = finger.contact
    k = stiffness(finger)
    # The support line: through the back beam's base, along its undeformed tangent, with
    # the normal pointing forward (toward the front beam's side).
    th = geo.theta[1]
    point = jnp.stack([geo.base[1, 0], geo.base[1, 2]])
    normal = -jnp.stack([jnp.cos(th), -jnp.sin(th)])  # -d1 of the back beam
    objects = [o.params() for o in finger.objects]
    head = jnp.stack(
        [
            k,
            smoothing(finger),
            c.friction,
            c.friction_regularisation,
            *c.slip_direction,
            *point,
            *normal,
            support_stiffness(finger),
            support_smoothing(finger),
        ]
    )
    return jnp.concatenate([head] + objects)


def _object_params(spec: ContactSpec, objects_flat):
    """(object class, its parameter slice) of every object."""
    out, i = [], 0
    for key, n in zip(spec.objects, spec.sizes):
        out.append((kind_by_key(key), objects_flat[i : i + n]))
        i += n
    return out


def contact_load(spec: ContactSpec, q, x, z, tx, tz, tau):
    """Contact force per length (fx, fz) and moment per length l_y on a beam point.

    q: the segment's contact columns (N_SEGMENT, then the global parameters).
    (x, z), (tx, tz): centreline point and unit tangent; tau in [0, 1] along the
    segment's flexible part. Everything is scalar arithmetic (no 2-vectors): it runs at
    every Runge-Kutta stage, where small vectors split the loop into many CPU kernels.
    """
    obj_flag, sup_flag, h0, h1 = q[0], q[1], q[2], q[3]
    g = q[N_SEGMENT:]
    k, delta, mu, eps = g[0], g[1], g[2], g[3]
    h = h0 + (h1 - h0) * tau
    fx = fz = ly = jnp.zeros_like(x)
    if spec.friction:
        slide = mu * jnp.tanh((g[4] * tx + g[5] * tz) / eps)
    for kind, params in _object_params(spec, g[N_GLOBAL:]):
        d, nx, nz = kind.distance_and_normal(params, x, z)
        qn = obj_flag * penalty(d - h, k, delta)
        fx, fz = fx + qn * nx, fz + qn * nz
        if spec.friction:
            ft = qn * slide  # friction force along t
            fx, fz = fx + ft * tx, fz + ft * tz
            # friction acts at the band's surface, p - h normal: l = (-h normal) x (ft t)
            ly = ly - h * ft * (nz * tx - nx * tz)
    if spec.support:
        s_nx, s_nz = g[8], g[9]
        gap = (x - g[6]) * s_nx + (z - g[7]) * s_nz
        qs = sup_flag * penalty(gap, g[10], g[11])
        fx, fz = fx + qs * s_nx, fz + qs * s_nz
    return fx, fz, ly


def beam_gaps(spec: ContactSpec, q, p, tau):
    """Gap of a beam point to every object and to the support (large when inactive)."""
    obj_flag, sup_flag, h0, h1 = q[0], q[1], q[2], q[3]
    g = q[N_SEGMENT:]
    h = h0 + (h1 - h0) * tau
    big = 1e6
    gaps = [
        jnp.where(obj_flag > 0, kind.distance(params, p) - h, big)
        for kind, params in _object_params(spec, g[N_GLOBAL:])
    ]
    if spec.support:
        gaps.append(jnp.where(sup_flag > 0, jnp.dot(p - g[6:8], g[8:10]), big))
    return jnp.stack(gaps)
