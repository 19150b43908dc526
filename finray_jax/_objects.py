"""Rigid objects in the finger plane, described by their signed distance.

Every object is an equinox Module of float arrays (centre, angle, sizes: design values
that never recompile). Its `kind` and, for a polygon, its vertex count are static. The
solver needs only two things from an object: its parameters as one flat vector
(`params`) and the signed distance of a point from its surface given those parameters,
negative inside, with its gradient, the outward normal (`distance_and_normal`, written
in closed form on scalars; `distance` is its first part). Points are (x, z) pairs; an
object's `angle` (rad) turns its local axes counter-clockwise in an x-z plot with x to
the right and z up.

Distances are exact outside the object and smooth there (C1 for the rounded shapes,
convex polygons and half-planes); every norm is a safe one, so gradients stay finite at
the surface. The ellipse's is exact inside too, its centre and axes included, with finite
gradients there (where the closest point is not unique, those of one of them).
"""

import dataclasses
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._types import as_float


def safe_norm(v, axis=-1):
    """|v| with a finite gradient at v = 0."""
    sq = jnp.sum(v * v, axis=axis)
    small = sq < 1e-30
    return jnp.where(small, 0.0, jnp.sqrt(jnp.where(small, 1.0, sq)))


def _safe_rsqrt(sq):
    """1 / sqrt(sq), and 0 where sq is (nearly) zero (the gradient of a safe norm there)."""
    small = sq < 1e-30
    return jnp.where(small, 0.0, rsqrt(jnp.where(small, 1.0, sq)))


def rsqrt(x):
    """1 / sqrt(x) as sqrt(x) / x. XLA's CPU backend does not vectorise its float64
    rsqrt, which makes it several times slower than a square root and a division, and
    rewrites 1 / sqrt(x) into it."""
    return jnp.sqrt(x) / x


def _atan2_first_quadrant(y, x):
    """atan2(y, x) for x, y >= 0; 0 at the origin, with a zero (not NaN) gradient."""
    origin = (x <= 0.0) & (y <= 0.0)
    return jnp.where(origin, 0.0, jnp.arctan2(y, jnp.where(origin, 1.0, x)))


def _acos_below_1(num, den):
    """acos(num / den) where 0 <= num < den, else 0; finite gradients either way."""
    below = num < den
    ratio = jnp.where(below, num / jnp.where(below, den, 1.0), 0.0)
    return jnp.where(below, jnp.arccos(ratio), 0.0)


def _local_scalars(q_center, angle, x, z):
    """(cos, sin, local x, local z) of world point (x, z) in an object's axes."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    dx, dz = x - q_center[0], z - q_center[1]
    return c, s, c * dx + s * dz, -s * dx + c * dz


def _to_world(c, s, gx, gz):
    """A gradient in an object's local axes as one in world axes."""
    return c * gx - s * gz, s * gx + c * gz


def _rotate(v, angle):
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


class AbstractObject(eqx.Module):
    """A rigid object in the x-z plane (a prism along y)."""

    kind: ClassVar[str]

    def params(self) -> Array:
        """All parameters as one flat float64 vector (layout known to `distance`)."""
        raise NotImplementedError

    @classmethod
    def distance(cls, q, p):
        """Signed distance of point p (x, z) from the surface, for parameters q."""
        return cls.distance_and_normal(q, p[0], p[1])[0]

    @classmethod
    def distance_and_normal(cls, q, x, z):
        """(d, nx, nz): the signed distance of point (x, z) and its gradient, the unit
        outward normal, as scalars.

        The contact rhs evaluates this at every Runge-Kutta stage, so each kind writes it
        in closed form on scalars: 2-vectors and a reverse pass there cut the loop body
        into many small kernels on the CPU."""
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

    @classmethod
    def distance_and_normal(cls, q, x, z):
        dx, dz = x - q[0], z - q[1]
        sq = dx * dx + dz * dz
        inv = _safe_rsqrt(sq)
        return sq * inv - q[2], dx * inv, dz * inv

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

    @classmethod
    def distance_and_normal(cls, q, x, z):
        a, b = q[2], q[3]
        c, s, lx, lz = _local_scalars(q[0:2], q[4], x, z)
        # Fold the point into the first quadrant (the signs are constants, so d|l|/dl is
        # +-1, also on an axis) and swap the axes if needed so that the major one comes
        # first: the point (X, Z) and semi-axes A >= B.
        sx, sz = jnp.where(lx < 0.0, -1.0, 1.0), jnp.where(lz < 0.0, -1.0, 1.0)
        swap = a < b
        big, small = jnp.where(swap, b, a), jnp.where(swap, a, b)
        X, Z = jnp.where(swap, sz * lz, sx * lx), jnp.where(swap, sx * lx, sz * lz)
        e2 = big * big - small * small

        def g_dg(t, e2, big, small, X, Z):
            st, ct = jnp.sin(t), jnp.cos(t)
            g = e2 * st * ct - big * X * st + small * Z * ct
            return g, e2 * (ct * ct - st * st) - big * X * ct - small * Z * st

        # The closest boundary point (A cos t, B sin t) has t in [0, pi/2], the one root
        # there of g(t) = (A^2 - B^2) sin t cos t - A X sin t + B Z cos t (g > 0 below
        # it, < 0 above; on an axis t = 0 or pi/2 can be a second, spurious root: a
        # farthest point). Newton on g from the near end of a bracket of the root, a
        # step that leaves the bracket bisects it instead, and every g narrows it:
        # - outside, atan(B Z / (A X)) <= t <= t_ray = atan(A Z / (B X)), from t_ray;
        # - inside, max(t_ray, acos(A X / (A^2 - B^2))) <= t <= acos(X / A) (the inward
        #   normal from the closest point meets the major axis between the centre and
        #   X), from the lower bound: this is exact on the axes and at the centre.
        # The search is not differentiated (its derivative, through steps that branch,
        # makes XLA's reverse pass orders of magnitude slower); one more Newton step after it
        # carries the derivative of the root (the implicit function theorem).
        sg = jax.lax.stop_gradient
        args = (sg(e2), sg(big), sg(small), sg(X), sg(Z))
        _, A, B, Xs, Zs = args
        t_ray = _atan2_first_quadrant(A * Zs, B * Xs)
        inside = (Xs / A) ** 2 + (Zs / B) ** 2 < 1.0
        lo = jnp.where(
            inside,
            jnp.maximum(t_ray, _acos_below_1(A * Xs, args[0])),
            _atan2_first_quadrant(B * Zs, A * Xs),
        )
        hi = jnp.where(inside, _acos_below_1(Xs, A), t_ray)
        t = jnp.where(inside, lo, t_ray)
        for _ in range(8):
            g, dg = g_dg(t, *args)
            up = g >= 0.0
            lo, hi = jnp.where(up, t, lo), jnp.where(up, hi, t)
            t_new = t - jnp.where(g == 0.0, 0.0, g / jnp.where(dg < 0.0, dg, -1.0))
            take = ((dg < 0.0) | (g == 0.0)) & (t_new >= lo) & (t_new <= hi)
            t = jnp.where(take, t_new, 0.5 * (lo + hi))
        # The differentiable step: its derivative always, its value where it stays in
        # the bracket (a bounded divisor keeps the derivative finite where dg ~ 0).
        g, dg = g_dg(t, e2, big, small, X, Z)
        newton = dg < -1e-100
        step = -g / jnp.where(newton, dg, -1.0)
        keep = newton & (t + step >= lo) & (t + step <= hi)
        t = t + step - sg(jnp.where(keep, 0.0, step))
        cx, cz = big * jnp.cos(t), small * jnp.sin(t)
        # The boundary's normal there; at the root it is the gradient.
        gx, gz = cx / (big * big), cz / (small * small)
        inv = _safe_rsqrt(gx * gx + gz * gz)
        gx, gz = gx * inv, gz * inv
        d = (X - cx) * gx + (Z - cz) * gz
        nx, nz = jnp.where(swap, gz, gx), jnp.where(swap, gx, gz)
        return (d, *_to_world(c, s, sx * nx, sz * nz))

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

    @classmethod
    def distance_and_normal(cls, q, x, z):
        r = q[4]
        c, s, lx, lz = _local_scalars(q[0:2], q[5], x, z)
        ex, ez = jnp.abs(lx) - (q[2] - r), jnp.abs(lz) - (q[3] - r)
        ox, oz = jnp.maximum(ex, 0.0), jnp.maximum(ez, 0.0)
        sq = ox * ox + oz * oz
        inv = _safe_rsqrt(sq)
        d = sq * inv + jnp.minimum(jnp.maximum(ex, ez), 0.0) - r
        # Outside the inner box: toward the nearest point of it; inside: across the
        # nearer side.
        x_side = ex >= ez
        gx = jnp.where(sq > 1e-30, ox * inv, jnp.where(x_side, 1.0, 0.0))
        gz = jnp.where(sq > 1e-30, oz * inv, jnp.where(x_side, 0.0, 1.0))
        return (d, *_to_world(c, s, jnp.sign(lx) * gx, jnp.sign(lz) * gz))

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

    @classmethod
    def distance_and_normal(cls, q, x, z):
        v = q[4:].reshape(-1, 2)
        k = v.shape[0]
        c, s, lx, lz = _local_scalars(q[0:2], q[3], x, z)
        # Per edge (unrolled, on scalars): the nearest point's offset w and the edge's
        # plane value; keep the smallest |w|^2 and the largest plane value.
        best_sq = best_wx = best_wz = top = top_nx = top_nz = None
        for i in range(k):
            ax, az, bx, bz = v[i, 0], v[i, 1], v[(i + 1) % k, 0], v[(i + 1) % k, 1]
            ex, ez, rx, rz = bx - ax, bz - az, lx - ax, lz - az
            el2 = ex * ex + ez * ez
            t = jnp.clip((rx * ex + rz * ez) / el2, 0.0, 1.0)
            wx, wz = rx - t * ex, rz - t * ez
            sq = wx * wx + wz * wz
            einv = _safe_rsqrt(el2)
            nx, nz = ez * einv, -ex * einv  # outward normal of a counter-clockwise edge
            plane = rx * nx + rz * nz
            if i == 0:
                best_sq, best_wx, best_wz, top, top_nx, top_nz = sq, wx, wz, plane, nx, nz
                continue
            nearer, beyond = sq < best_sq, plane > top
            best_sq = jnp.where(nearer, sq, best_sq)
            best_wx = jnp.where(nearer, wx, best_wx)
            best_wz = jnp.where(nearer, wz, best_wz)
            top = jnp.where(beyond, plane, top)
            top_nx = jnp.where(beyond, nx, top_nx)
            top_nz = jnp.where(beyond, nz, top_nz)
        inv = _safe_rsqrt(best_sq)
        outside = top > 0.0
        d = jnp.where(outside, best_sq * inv, top) - q[2]
        gx = jnp.where(outside, best_wx * inv, top_nx)
        gz = jnp.where(outside, best_wz * inv, top_nz)
        return (d, *_to_world(c, s, gx, gz))

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
        return jnp.concatenate([self.point, self.normal / safe_norm(self.normal)])

    @classmethod
    def distance_and_normal(cls, q, x, z):
        return (x - q[0]) * q[2] + (z - q[1]) * q[3], q[2], q[3]

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


def kind_by_key(key: tuple):
    """The object class of a layout key (its `distance` and `distance_and_normal`)."""
    return OBJECT_KINDS[key[0]]


def param_size(key: tuple) -> int:
    sizes = {"circle": 3, "ellipse": 5, "rounded_rectangle": 6, "half_plane": 4}
    if key[0] == "polygon":
        return 4 + 2 * key[1]
    return sizes[key[0]]
