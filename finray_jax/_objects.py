"""Rigid objects in the finger plane, described by their signed distance.

Every object is an equinox Module of float arrays (centre, angle, sizes: design values
that never recompile). Its `kind` and, for a polygon, its vertex count are static. The
solver needs only two things from an object: its parameters as one flat vector
(`params`) and the signed distance of a point from its surface given those parameters
(`distance`, negative inside). Points are (x, z) pairs; an object's `angle` (rad) turns
its local axes counter-clockwise in an x-z plot with x to the right and z up.

Distances are exact outside the object and smooth there (C1 for the rounded shapes,
convex polygons and half-planes); every norm is a safe one, so gradients stay finite at
the surface.
"""

import dataclasses
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._types import as_float


def _safe_norm(v, axis=-1):
    """|v| with a finite gradient at v = 0."""
    sq = jnp.sum(v * v, axis=axis)
    small = sq < 1e-30
    return jnp.where(small, 0.0, jnp.sqrt(jnp.where(small, 1.0, sq)))


def _to_local(p, center, angle):
    """Coordinates of world point p (x, z) in an object's axes."""
    d = p - center
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def _rotate(v, angle):
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


class AbstractObject(eqx.Module):
    """A rigid object in the x-z plane (a prism along y)."""

    kind: ClassVar[str]

    def params(self) -> Array:
        """All parameters as one flat float64 vector (layout known to `distance`)."""
        raise NotImplementedError

    @staticmethod
    def distance(q, p):
        """Signed distance of point p (x, z) from the surface, for parameters q."""
        raise NotImplementedError

    def key(self) -> tuple:
        """What fixes the parameter layout (static)."""
        return (self.kind,)

    def moved(self, displacement) -> "AbstractObject":
        """The same object translated by `displacement` (x, z)."""
        return dataclasses.replace(self, center=self.center + as_float(displacement))

    def signed_distance(self, p):
        """Signed distance of world point(s) p (..., 2) from this object's surface."""
        return _signed_distance(self, as_float(p))

    def bounds(self) -> np.ndarray:
        """Axis-aligned bounding box [[xmin, zmin], [xmax, zmax]] (may be infinite)."""
        raise NotImplementedError

    def outline(self, n: int = 200) -> np.ndarray:
        """Points (n, 2) on the boundary, for plots (a half-plane gives a long segment)."""
        raise NotImplementedError


@eqx.filter_jit
def _signed_distance(obj: AbstractObject, p):
    q = obj.params()
    d = jax.vmap(lambda x: obj.distance(q, x))(p.reshape(-1, 2))
    return d.reshape(p.shape[:-1])


class Circle(AbstractObject):
    """A cylinder along y: centre (x, z) and radius (mm)."""

    kind: ClassVar[str] = "circle"
    center: Float[Array, "2"] = eqx.field(converter=as_float)
    radius: Float[Array, ""] = eqx.field(converter=as_float)

    def params(self):
        return jnp.concatenate([self.center, self.radius[None]])

    @staticmethod
    def distance(q, p):
        return _safe_norm(p - q[0:2]) - q[2]

    def bounds(self):
        c, r = np.asarray(self.center), float(self.radius)
        return np.array([c - r, c + r])

    def outline(self, n=200):
        t = np.linspace(0.0, 2.0 * np.pi, n)
        r = float(self.radius)
        return np.asarray(self.center) + r * np.stack([np.cos(t), np.sin(t)], axis=-1)


class Ellipse(AbstractObject):
    """An elliptic cylinder: centre, semi-axes (a along its local x, b along local z),
    angle (rad)."""

    kind: ClassVar[str] = "ellipse"
    center: Float[Array, "2"] = eqx.field(converter=as_float)
    semi_axes: Float[Array, "2"] = eqx.field(converter=as_float)
    angle: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)

    def params(self):
        return jnp.concatenate([self.center, self.semi_axes, self.angle[None]])

    @staticmethod
    def distance(q, p):
        a, b = q[2], q[3]
        local = _to_local(p, q[0:2], q[4])
        x, z = jnp.abs(local[0]), jnp.abs(local[1])
        # Closest boundary point (a cos t, b sin t), t in [0, pi/2], by Newton on the
        # stationarity condition g(t) = (a^2 - b^2) sin t cos t - a x sin t + b z cos t.
        t = jnp.arctan2(a * z, b * x)
        for _ in range(8):
            st, ct = jnp.sin(t), jnp.cos(t)
            g = (a * a - b * b) * st * ct - a * x * st + b * z * ct
            dg = (a * a - b * b) * (ct * ct - st * st) - a * x * ct - b * z * st
            dg = jnp.where(jnp.abs(dg) < 1e-30, -1e-30, dg)
            t = jnp.clip(t - g / dg, 0.0, 0.5 * jnp.pi)
        cx, cz = a * jnp.cos(t), b * jnp.sin(t)
        normal = jnp.stack([cx / (a * a), cz / (b * b)])
        normal = normal / _safe_norm(normal)
        return (x - cx) * normal[0] + (z - cz) * normal[1]

    def bounds(self):
        pts = self.outline(400)
        return np.array([pts.min(axis=0), pts.max(axis=0)])

    def outline(self, n=200):
        t = np.linspace(0.0, 2.0 * np.pi, n)
        a, b = np.asarray(self.semi_axes)
        local = np.stack([a * np.cos(t), b * np.sin(t)], axis=-1)
        return np.asarray(self.center) + np.asarray(_rotate(local, float(self.angle)))


class RoundedRectangle(AbstractObject):
    """A box: centre, half sizes (local x, local z), corner radius, angle (rad)."""

    kind: ClassVar[str] = "rounded_rectangle"
    center: Float[Array, "2"] = eqx.field(converter=as_float)
    half_size: Float[Array, "2"] = eqx.field(converter=as_float)
    corner_radius: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)
    angle: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)

    def params(self):
        return jnp.concatenate(
            [self.center, self.half_size, self.corner_radius[None], self.angle[None]]
        )

    @staticmethod
    def distance(q, p):
        r = q[4]
        local = jnp.abs(_to_local(p, q[0:2], q[5]))
        e = local - (q[2:4] - r)
        outside = _safe_norm(jnp.maximum(e, 0.0))
        inside = jnp.minimum(jnp.maximum(e[0], e[1]), 0.0)
        return outside + inside - r

    def bounds(self):
        pts = self.outline(400)
        return np.array([pts.min(axis=0), pts.max(axis=0)])

    def outline(self, n=200):
        hx, hz = np.asarray(self.half_size)
        r = float(self.corner_radius)
        k = max(n // 4, 2)
        pts = []
        for cx, cz, t0 in (
            (hx - r, hz - r, 0.0),
            (-hx + r, hz - r, 0.5),
            (-hx + r, -hz + r, 1.0),
            (hx - r, -hz + r, 1.5),
        ):
            t = np.pi * (t0 + 0.5 * np.linspace(0.0, 1.0, k))
            pts.append(np.stack([cx + r * np.cos(t), cz + r * np.sin(t)], axis=-1))
        local = np.concatenate(pts + [pts[0][:1]])
        return np.asarray(self.center) + np.asarray(_rotate(local, float(self.angle)))


class Polygon(AbstractObject):
    """A convex polygon: vertices (k, 2) in its local axes, counter-clockwise, placed at
    `center` and turned by `angle`; corners rounded by `corner_radius` (the outline grows
    by that radius)."""

    kind: ClassVar[str] = "polygon"
    vertices: Float[Array, "k 2"] = eqx.field(converter=as_float)
    center: Float[Array, "2"] = eqx.field(converter=as_float, default=(0.0, 0.0))
    corner_radius: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)
    angle: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)

    def key(self):
        return (self.kind, int(self.vertices.shape[0]))

    def params(self):
        return jnp.concatenate(
            [self.center, self.corner_radius[None], self.angle[None], self.vertices.reshape(-1)]
        )

    @staticmethod
    def distance(q, p):
        v = q[4:].reshape(-1, 2)
        local = _to_local(p, q[0:2], q[3])
        a, b = v, jnp.roll(v, -1, axis=0)
        edge = b - a
        rel = local - a
        t = jnp.clip(jnp.sum(rel * edge, axis=-1) / jnp.sum(edge * edge, axis=-1), 0.0, 1.0)
        seg = _safe_norm(rel - t[:, None] * edge)
        # Outward normals of a counter-clockwise polygon: (ez, -ex).
        normal = jnp.stack([edge[:, 1], -edge[:, 0]], axis=-1) / _safe_norm(edge)[:, None]
        plane = jnp.sum(rel * normal, axis=-1)
        outside = jnp.max(plane) > 0.0  # convex: outside iff beyond some edge's line
        return jnp.where(outside, jnp.min(seg), jnp.max(plane)) - q[2]

    def bounds(self):
        pts = self.outline(400)
        return np.array([pts.min(axis=0), pts.max(axis=0)])

    def outline(self, n=200):
        v = np.asarray(self.vertices)
        r = float(self.corner_radius)
        pts = []
        k = max(n // len(v), 2)
        for i in range(len(v)):
            prev, cur, nxt = v[i - 1], v[i], v[(i + 1) % len(v)]
            e0, e1 = cur - prev, nxt - cur
            a0 = np.arctan2(-e0[0], e0[1])  # outward normal angle of the incoming edge
            a1 = np.arctan2(-e1[0], e1[1])
            if a1 < a0:
                a1 += 2.0 * np.pi
            t = np.linspace(a0, a1, k)
            pts.append(cur + r * np.stack([np.cos(t), np.sin(t)], axis=-1))
        local = np.concatenate(pts + [pts[0][:1]])
        return np.asarray(self.center) + np.asarray(_rotate(local, float(self.angle)))


class HalfPlane(AbstractObject):
    """Everything behind a line: the object occupies {x : (x - point) . normal < 0}."""

    kind: ClassVar[str] = "half_plane"
    point: Float[Array, "2"] = eqx.field(converter=as_float)
    normal: Float[Array, "2"] = eqx.field(converter=as_float)

    @property
    def center(self):
        return self.point

    def moved(self, displacement):
        return dataclasses.replace(self, point=self.point + as_float(displacement))

    def params(self):
        return jnp.concatenate([self.point, self.normal / _safe_norm(self.normal)])

    @staticmethod
    def distance(q, p):
        return jnp.dot(p - q[0:2], q[2:4])

    def bounds(self):
        n = np.asarray(self.normal) / np.linalg.norm(np.asarray(self.normal))
        lo = np.full(2, -np.inf)
        hi = np.full(2, np.inf)
        # A half-plane with an axis-aligned normal is bounded on one side.
        for i in range(2):
            if abs(n[1 - i]) < 1e-12:
                if n[i] > 0:
                    hi[i] = float(np.asarray(self.point)[i])
                else:
                    lo[i] = float(np.asarray(self.point)[i])
        return np.array([lo, hi])

    def outline(self, n=2, half_length=200.0):
        nn = np.asarray(self.normal) / np.linalg.norm(np.asarray(self.normal))
        t = np.array([-nn[1], nn[0]])
        p = np.asarray(self.point)
        return np.stack([p - half_length * t, p + half_length * t])


OBJECT_KINDS = {c.kind: c for c in (Circle, Ellipse, RoundedRectangle, Polygon, HalfPlane)}


def distance_by_key(key: tuple):
    """The static distance function of an object layout key."""
    return OBJECT_KINDS[key[0]].distance


def param_size(key: tuple) -> int:
    sizes = {"circle": 3, "ellipse": 5, "rounded_rectangle": 6, "half_plane": 4}
    if key[0] == "polygon":
        return 4 + 2 * key[1]
    return sizes[key[0]]
