"""The segment table (traced): every segment's arc length, rigid part, stiffness samples,
distributed load, undeformed frame and contact columns, from the design's values."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._abstract_rod import TAPER_NODES
from ._contact import global_params
from ._finger import Finger, PointLoad
from ._geometry import Geometry, arc_point, section_stiffness
from ._topology import Topology


class SegmentTable(eqx.Module):
    start_s: jax.Array  # (S,)
    length: jax.Array  # (S,)
    rigid: jax.Array  # (S,) length held rigidly by an adaptor clamp
    contact: jax.Array  # (S, N_SEGMENT + globals) contact columns, or (S, 0)
    stiffness: jax.Array  # (S, 4, 6): kGA1, kGA2, EA, EI1, EI2, GJ at TAPER_NODES
    force: jax.Array  # (S, 3) distributed force per length (at load factor 1)
    precurvature: jax.Array  # (S, 3)
    theta: jax.Array  # (S,) undeformed frame angle
    point: jax.Array  # (S, 3) undeformed start point
    half: jax.Array | None = None  # (S, 2) half-thickness at the flexible part's ends


def _anchors(topo: Topology, finger: Finger, geo: Geometry):
    cb, ad = finger.crossbeams, finger.adaptor
    first = [ld.s if isinstance(ld, PointLoad) else ld.s_range[0] for ld in finger.loads]
    second = [ld.s if isinstance(ld, PointLoad) else ld.s_range[1] for ld in finger.loads]
    support = jnp.zeros(()) if ad.support_length is None else ad.support_length
    parts = [jnp.zeros(1), geo.length, cb.front_s, cb.back_s]
    parts += [jnp.stack(first), jnp.stack(second)] if finger.loads else []
    return jnp.concatenate(parts + [support[None]])


def segment_table(topo: Topology, finger: Finger, geo: Geometry) -> SegmentTable:
    lay = topo.layout
    beams = lay.beam
    anchors = _anchors(topo, finger, geo)
    start_s = jnp.asarray(lay.start) @ anchors
    length = jnp.asarray(lay.end) @ anchors - start_s
    ad, cb = finger.adaptor, finger.crossbeams
    zero_c = jnp.zeros(topo.n_crossbeams)
    clamp = jnp.concatenate([jnp.stack([ad.front_clamp_length, ad.back_clamp_length]), zero_c])
    # min(max(clamp - s0, 0), length), ties resolved toward the clamp: a zero-length
    # segment (two events at one arc length) has no rigid part on either side of the tie,
    # where jnp.clip's min would pass half of d(length) into d(rigid).
    reach = jnp.maximum(clamp[beams] - start_s, 0.0)
    rigid = jnp.where(reach <= length, reach, length)

    # Sections: thickness linear from base (t0) to tip (t1) along each beam.
    def ends(sec):
        tip = sec.thickness if sec.tip_thickness is None else sec.tip_thickness
        return sec.thickness, tip

    (f0, f1), (b0, b1) = ends(finger.front), ends(finger.back)
    t0 = jnp.concatenate([jnp.stack([f0, b0]), cb.thickness])[beams]
    t1 = jnp.concatenate([jnp.stack([f1, b1]), cb.thickness])[beams]
    depth = jnp.concatenate([jnp.stack([finger.front.depth, finger.back.depth]), cb.depth])
    nodes = (start_s + rigid)[:, None] + jnp.asarray(TAPER_NODES)[None] * (length - rigid)[:, None]
    thick = t0[:, None] + (t1 - t0)[:, None] * nodes / geo.length[beams][:, None]
    stiffness = section_stiffness(finger.material, thick, depth[beams][:, None], finger.torsion)

    per_length = [
        jnp.zeros(3) if isinstance(ld, PointLoad) else ld.force_per_length for ld in finger.loads
    ]
    force = (
        jnp.asarray(lay.loads) @ jnp.stack(per_length) if per_length else jnp.zeros((len(beams), 3))
    )

    kappa = geo.curvature[beams]
    theta = geo.theta[beams] + kappa * start_s
    point = jax.vmap(arc_point)(geo.base[beams], geo.theta[beams], kappa, start_s)
    zero = jnp.zeros_like(kappa)
    if topo.contact is None:
        contact = jnp.zeros((len(beams), 0))
    else:
        main = jnp.asarray((beams < 2).astype(np.float64))
        support = jnp.asarray(lay.supported) * float(topo.contact.support)
        half = 0.5 * thick[:, jnp.asarray([0, 3])]
        shared = global_params(finger, geo)
        contact = jnp.concatenate(
            [
                main[:, None],
                support[:, None],
                half,
                jnp.broadcast_to(shared, (len(beams), shared.shape[0])),
            ],
            axis=1,
        )
    return SegmentTable(
        start_s=start_s,
        length=length,
        rigid=rigid,
        contact=contact,
        stiffness=stiffness,
        force=force,
        precurvature=jnp.stack([zero, kappa, zero], axis=-1),
        theta=theta,
        point=point,
        half=0.5 * thick[:, jnp.asarray([0, 3])],
    )
