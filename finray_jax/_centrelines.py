"""The main beams' undeformed centrelines and how close they come, traced: what the geometry
rules of `_rules` read (a base too close to the other beam, the beams crossing, the beams
too close away from the tip, a crossbeam too short).

A finger's beams are numbered front (FRONT = 0), back (BACK = 1), then crossbeam i as 2 + i.
Each main beam is sampled at `CENTRELINE_SAMPLES` points, and measured against the other
beam's polyline: its two ends when it is straight, its samples when it is an arc.
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

FRONT, BACK = 0, 1
CENTRELINE_SAMPLES = 101  # points a main beam's centreline is sampled at


class Lines(NamedTuple):
    """Both main beams' undeformed centrelines, front then back on the leading axis."""

    s: jax.Array  # (2, n) arc lengths, 0 to the beam's length
    p: jax.Array  # (2, n, 2) points (x, z), the last one the tip exactly
    t0: jax.Array  # (2,) thickness at the base
    t1: jax.Array  # (2,) thickness at the tip
    length: jax.Array  # (2,)
    curvature: jax.Array  # (2,)
    tangent_at_tip: jax.Array  # (2, 2) unit tangent (x, z), base to tip

    def half(self, s, beam=slice(None)):
        """Half thickness at arc lengths s: of both beams (s of shape (2, ...), front
        first), or of one (beam = FRONT or BACK)."""
        t0, t1, length = self.t0[beam], self.t1[beam], self.length[beam]
        if isinstance(beam, slice):
            shape = (-1,) + (1,) * (jnp.ndim(s) - 1)
            t0, t1, length = (x.reshape(shape) for x in (t0, t1, length))
        return 0.5 * (t0 + (t1 - t0) * s / length)


def main_lines(finger, geo, straight: bool, n: int = CENTRELINE_SAMPLES) -> Lines:
    """The front and back beams' centrelines at n points each, as `_geometry.arc_point`
    computes them (a circular arc of constant precurvature, or a straight line).
    straight=True: both beams are known to be straight; the points are those of an arc of
    zero curvature (the same numbers), with one sine and one cosine a beam."""
    base = geo.base[:2, ::2]
    theta, kappa, length = geo.theta[:2], geo.curvature[:2], geo.length[:2]
    s = jnp.linspace(0.0, length, n, axis=-1)  # (2, n)
    if straight:  # theta + 0.5 * 0 * s == theta, s * sinc(0) == s
        direction = jnp.stack([jnp.sin(theta), jnp.cos(theta)], axis=-1)[:, None]
        p = base[:, None] + s[..., None] * direction
    else:
        half = theta[:, None] + 0.5 * kappa[:, None] * s
        r = s * jnp.sinc(0.5 * kappa[:, None] * s / jnp.pi)  # sinc(x) = sin(pi x) / (pi x)
        p = base[:, None] + r[..., None] * jnp.stack([jnp.sin(half), jnp.cos(half)], axis=-1)
    p = p.at[:, -1].set(finger.tip)  # the shared tip exactly
    sections = (finger.front, finger.back)
    t0 = jnp.stack([sec.thickness for sec in sections])
    t1 = jnp.stack(
        [sec.thickness if sec.tip_thickness is None else sec.tip_thickness for sec in sections]
    )
    end = theta + kappa * length
    tangent = jnp.stack([jnp.sin(end), jnp.cos(end)], axis=-1)
    return Lines(s, p, t0, t1, length, kappa, tangent)


def polylines(lines: Lines, ends_only: bool):
    """(arc lengths (2, m), points (2, m, 2)) of the polylines other points are measured
    against: a beam's two ends when it is straight, its points when it is an arc.
    ends_only=False gives a fixed size whatever the curvatures (traced values): a straight
    beam's polyline is then its base repeated, then its tip, whose zero-length segments
    measure nothing (`nearest` leaves them out) and cross nothing."""
    ends = jnp.array([0, -1])
    if ends_only:
        return lines.s[:, ends], lines.p[:, ends]
    straight = (lines.curvature == 0.0)[:, None]
    ends_s = jnp.zeros_like(lines.s).at[:, -1].set(lines.length)
    ends_p = jnp.broadcast_to(lines.p[:, :1], lines.p.shape).at[:, -1].set(lines.p[:, -1])
    path_s = jnp.where(straight, ends_s, lines.s)
    return path_s, jnp.where(straight[..., None], ends_p, lines.p)


def nearest(path_s, path_p, points):
    """Distance from each point (k, 2) to a polyline (arc lengths (m,), points (m, 2)), and
    the arc length of the nearest point on it (the first nearest segment's). Zero-length
    segments (the padding of `polylines`) are left out.

    This runs per design in every batch, so it is written for the CPU: one division per
    segment rather than per pair, squared distances (a square root per point), the nearest
    segment picked by integer reductions rather than argmin and a gather. (Where only the
    distance is used, the arc length is dropped from the compiled code.)"""
    ax, az = path_p[:-1, 0], path_p[:-1, 1]
    ex, ez = jnp.diff(path_p[:, 0]), jnp.diff(path_p[:, 1])
    den = ex * ex + ez * ez
    real = den > 0.0
    inv = 1.0 / jnp.where(real, den, 1.0)
    rx, rz = points[:, :1] - ax, points[:, 1:] - az  # (k, m - 1)
    t = jnp.clip((rx * ex + rz * ez) * inv, 0.0, 1.0)
    qx, qz = rx - t * ex, rz - t * ez
    # (the select also keeps XLA's CPU backend from splitting this into several passes)
    q = jnp.where(real, qx * qx + qz * qz, jnp.inf)
    q_min = jnp.min(q, axis=1)
    seg = jnp.arange(q.shape[1])
    j = jnp.min(jnp.where(q == q_min[:, None], seg, q.shape[1]), axis=1)  # argmin
    s = path_s[:-1] + t * jnp.diff(path_s)
    return jnp.sqrt(q_min), jnp.sum(jnp.where(seg == j[:, None], s, 0.0), axis=1)


class Crossing(NamedTuple):
    """Whether the back beam's polyline crosses the front beam's before the tip they
    share, and where it first does (back segment first): meaningful only when `crosses`."""

    crosses: jax.Array  # bool
    back_s: jax.Array
    front_s: jax.Array
    point: jax.Array  # (2,) (x, z)


def crossing(front_s, front_p, back_s, back_p) -> Crossing:
    """`Crossing` of two polylines (arc lengths (m,), points (m, 2)): a back segment and a
    front segment cross when each one's ends lie strictly on both sides of the other. The
    side of every vertex of one polyline relative to every segment of the other is
    computed once."""
    P, Q = back_p, front_p
    ax, az = P[:-1, 0, None], P[:-1, 1, None]  # back segments (i), down
    bx, bz = jnp.diff(P[:, 0])[:, None], jnp.diff(P[:, 1])[:, None]
    cx, cz = Q[None, :-1, 0], Q[None, :-1, 1]  # front segments (j), across
    dx, dz = jnp.diff(Q[:, 0])[None], jnp.diff(Q[:, 1])[None]
    side_q = bx * (Q[None, :, 1] - az) - bz * (Q[None, :, 0] - ax)  # front vertices, (i, j)
    side_p = dx * (P[:, None, 1] - cz) - dz * (P[:, None, 0] - cx)  # back vertices, (i, j)
    d1, d2 = side_q[:, :-1], side_q[:, 1:]  # sides of the front segment's ends
    d3, d4 = side_p[:-1], side_p[1:]  # sides of the back segment's ends
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    hit = hit.at[-1, -1].set(False)  # the last segments meet at the tip
    i, j = jnp.unravel_index(jnp.argmax(hit), hit.shape)  # the first crossing
    ta = d3[i, j] / (d3[i, j] - d4[i, j])
    tc = d1[i, j] / (d1[i, j] - d2[i, j])
    sb = back_s[i] + ta * (back_s[i + 1] - back_s[i])
    sf = front_s[j] + tc * (front_s[j + 1] - front_s[j])
    return Crossing(jnp.any(hit), sb, sf, P[i] + ta * (P[i + 1] - P[i]))


class Clearance(NamedTuple):
    """How close the main beams come: what the geometry rules test and their messages
    name. Rows are the beams, front then back; each beam's samples are measured against
    the other beam's polyline."""

    lines: Lines
    distance: jax.Array  # (2, n) from each sample to the other beam
    other_s: jax.Array  # (2, n) arc length of the nearest point on the other beam
    least: jax.Array  # (2, n) the clearance needed there: the two half thicknesses
    crossing: Crossing
    zone: jax.Array  # the exempt length before the tip
    outside_zone: jax.Array  # (2, n) bool: samples at least `zone` from the tip


def _clearance(finger, geo, straight: bool) -> Clearance:
    lines = main_lines(finger, geo, straight)
    # Near the tip the beams necessarily come together: within r of it, the centrelines
    # of two beams meeting at an angle alpha lie about r sin(alpha) apart. Exempt twice the
    # distance over which that is less than the two half thicknesses at the tip (alpha
    # capped at 90 degrees), but never more than a quarter of the shorter beam's length.
    cos_alpha = jnp.clip(lines.tangent_at_tip[FRONT] @ lines.tangent_at_tip[BACK], -1.0, 1.0)
    sin_alpha = jnp.where(cos_alpha <= 0.0, 1.0, jnp.sqrt(1.0 - cos_alpha**2))
    at_tip = lines.half(lines.length[FRONT], FRONT) + lines.half(lines.length[BACK], BACK)
    zone = 0.25 * jnp.minimum(lines.length[FRONT], lines.length[BACK])
    shorter = 2.0 * at_tip < zone * sin_alpha
    zone = jnp.where(shorter, 2.0 * at_tip / jnp.where(shorter, sin_alpha, 1.0), zone)

    path_s, path_p = polylines(lines, straight)
    cross = crossing(path_s[FRONT], path_p[FRONT], path_s[BACK], path_p[BACK])
    other = jnp.array([BACK, FRONT])
    d, s_other = jax.vmap(nearest)(path_s[other], path_p[other], lines.p)  # (2, n) each
    other_lines = Lines(*(x[other] for x in lines))
    # The nearest arc length matters only on a tapered beam (0.5 (t0 + 0 s / L) is the
    # same at every s): untapered, the clearance leaves it out.
    tapered = any(sec.tip_thickness is not None for sec in (finger.front, finger.back))
    least = lines.half(lines.s) + other_lines.half(s_other if tapered else 0.0 * lines.s)
    outside = jnp.linalg.norm(lines.p - finger.tip, axis=-1) >= zone
    return Clearance(lines, d, s_other, least, cross, zone, outside)


def clearance(finger, geo) -> Clearance:
    """The main beams' `Clearance` in the undeformed finger."""
    # Two straight beams (the usual case) need only their ends as polylines, a hundredth
    # of the work, where the branch is taken: one design at a time (as a batch runs on
    # the CPU by default), or a vmapped batch whose curvatures are not batched (a batch
    # over a curvature computes both branches).
    return jax.lax.cond(
        (geo.curvature[FRONT] == 0.0) & (geo.curvature[BACK] == 0.0),
        functools.partial(_clearance, finger, geo, True),
        functools.partial(_clearance, finger, geo, False),
    )
