"""Eager checks of a finger that are not rules of its design values (`_rules`): the shapes
of its fields, that every number is finite, the contact model and the objects. Each raises
a FingerError that names the field and the value."""

import os
import sys
import warnings

import jax
import numpy as np

from ._centrelines import BACK, FRONT
from ._errors import FingerError, FingerWarning
from ._geometry import main_beam_samples
from ._objects import AbstractObject

_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message: str) -> None:
    """warnings.warn(message, FingerWarning) attributed to the first caller outside
    finray_jax (the user's line that solved, validated or read the finger)."""
    level, frame = 1, sys._getframe(0)
    while frame.f_back is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, FingerWarning, stacklevel=level)


def numbers(x):
    return np.asarray(x, dtype=np.float64)


def finite(name, value):
    v = numbers(value)
    if not np.all(np.isfinite(v)):
        raise FingerError(f"{name} must be finite, got {v.tolist()}")
    return v


def shaped(name, value, shape):
    v = numbers(value)
    if v.shape != shape:
        want = "a number" if shape == () else f"{shape[0]} numbers"
        raise FingerError(f"{name} must be {want}, got {v.tolist()}")
    return v


def positive(name, value):
    v = finite(name, value)
    if np.any(v <= 0):
        raise FingerError(f"{name} must be positive, got {v.tolist()}")
    return v


def check_shapes(finger) -> None:
    """The shapes of the fields the rules read: crossbeam arrays 1-D of equal length,
    points (x, z), everything else one number."""
    cb = finger.crossbeams
    shapes = {k: np.shape(getattr(cb, k)) for k in ("front_s", "back_s", "thickness", "depth")}
    if len(set(shapes.values())) != 1 or len(shapes["front_s"]) != 1:
        raise FingerError(f"crossbeam arrays must be 1-D of equal length, got shapes {shapes}")
    for name in ("front_base", "back_base", "tip"):
        v = numbers(getattr(finger, name))
        if v.shape != (2,):
            raise FingerError(f"{name} must be a point (x, z), got {v.tolist()}")
    scalars = {f"material.{k}": getattr(finger.material, k) for k in ("E", "nu")}
    scalars["material.shear_coefficient"] = finger.material.shear_coefficient
    for beam in ("front", "back"):
        sec = getattr(finger, beam)
        for k in ("thickness", "tip_thickness", "depth"):
            scalars[f"{beam}.{k}"] = getattr(sec, k)
        scalars[f"{beam}_curvature"] = getattr(finger, f"{beam}_curvature")
    for k in ("front_clamp_length", "back_clamp_length", "support_length"):
        scalars[f"adaptor.{k}"] = getattr(finger.adaptor, k)
    for name, value in scalars.items():
        if value is not None:
            shaped(name, value, ())


def check_finite(finger) -> None:
    """Every number of the finger finite; the message names the first field that is not
    (a crossbeam array by the crossbeam)."""
    for path, leaf in jax.tree_util.tree_leaves_with_path(finger):
        if not hasattr(leaf, "dtype"):
            continue
        v = numbers(leaf)
        if np.all(np.isfinite(v)):
            continue
        name = jax.tree_util.keystr(path).lstrip(".")
        if name.startswith("crossbeams.") and v.ndim == 1:
            i = int(np.argmin(np.isfinite(v)))
            name, v = name.replace("crossbeams.", f"crossbeams[{i}].", 1), v[i]
        raise FingerError(f"{name} must be finite, got {v.tolist()}")


def check_contact(finger) -> None:
    """The contact model's values, the objects, and that no object overlaps a main beam
    at the start."""
    c = finger.contact
    if c.stiffness is not None:
        positive("contact.stiffness", shaped("contact.stiffness", c.stiffness, ()))
    mp = float(finite("contact.max_penetration", c.max_penetration))
    if not 0.0 < mp < 0.5:
        raise FingerError(
            f"contact.max_penetration must lie in (0, 0.5) (a fraction of the "
            f"front beam's thickness), got {mp}"
        )
    if c.support_stiffness is not None:
        positive(
            "contact.support_stiffness",
            shaped("contact.support_stiffness", c.support_stiffness, ()),
        )
    if c.max_support_penetration is not None:
        ms = float(finite("contact.max_support_penetration", c.max_support_penetration))
        if not 0.0 < ms < 0.5:
            raise FingerError(
                f"contact.max_support_penetration must lie in (0, 0.5) (a fraction of the "
                f"back beam's thickness), got {ms}"
            )
    mu = float(finite("contact.friction", c.friction))
    if mu < 0:
        raise FingerError(f"contact.friction must be non-negative, got {mu}")
    positive("contact.friction_regularisation", c.friction_regularisation)
    shaped("contact.slip_direction", finite("contact.slip_direction", c.slip_direction), (2,))
    if not (isinstance(c.segment_length, (int, float)) and c.segment_length > 0):
        raise FingerError(f"contact.segment_length must be positive, got {c.segment_length!r}")
    near = c.near_segments
    if near is not None and not (isinstance(near, int) and not isinstance(near, bool) and near > 0):
        raise FingerError(
            "contact.near_segments must be a positive integer or None (every segment), "
            f"got {near!r}"
        )
    for i, obj in enumerate(finger.objects):
        _check_object(f"objects[{i}]", obj)
    for i, obj in enumerate(finger.objects):
        hit = _overlap(finger, obj)
        if hit is not None:
            beam, s, depth = hit
            raise FingerError(
                f"objects[{i}] ({obj.kind}) overlaps the {beam} beam at the start, at s = "
                f"{s:.4g} mm by {depth:.4g} mm: place objects clear of the finger (the grasp "
                "closes the finger onto them)"
            )


def _check_object(where: str, obj) -> None:
    if not isinstance(obj, AbstractObject):
        raise FingerError(f"{where} is not an object (Circle, Ellipse, ...): {obj!r}")
    for name in ("center", "point", "normal"):
        if hasattr(obj, name):
            shaped(f"{where}.{name}", finite(f"{where}.{name}", getattr(obj, name)), (2,))
    kind = obj.kind
    if kind == "circle":
        positive(f"{where}.radius", shaped(f"{where}.radius", obj.radius, ()))
    elif kind == "ellipse":
        positive(f"{where}.semi_axes", shaped(f"{where}.semi_axes", obj.semi_axes, (2,)))
        finite(f"{where}.angle", obj.angle)
    elif kind == "rounded_rectangle":
        half = positive(f"{where}.half_size", shaped(f"{where}.half_size", obj.half_size, (2,)))
        r = float(finite(f"{where}.corner_radius", obj.corner_radius))
        if not 0.0 <= r <= float(np.min(half)):
            raise FingerError(
                f"{where}.corner_radius must lie in [0, {float(np.min(half))}] "
                f"(the smaller half size), got {r}"
            )
        finite(f"{where}.angle", obj.angle)
    elif kind == "polygon":
        _check_polygon(where, obj)
    elif kind == "half_plane":
        normal = numbers(obj.normal)
        if np.linalg.norm(normal) == 0:
            raise FingerError(f"{where}.normal must be non-zero, got {normal.tolist()}")


def _check_polygon(where: str, obj) -> None:
    v = finite(f"{where}.vertices", obj.vertices)
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
        raise FingerError(f"{where}.vertices must be 3 or more (x, z) points, got {v.tolist()}")
    e = np.roll(v, -1, axis=0) - v
    turn = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if np.any(turn <= 0):
        raise FingerError(
            f"{where}.vertices must form a convex polygon listed counter-"
            f"clockwise (x right, z up), got {v.tolist()}"
        )
    r = float(finite(f"{where}.corner_radius", obj.corner_radius))
    if r < 0:
        raise FingerError(f"{where}.corner_radius must be non-negative, got {r}")


def _overlap(finger, obj, samples: int = 401):
    """(beam, s, depth) of the deepest overlap of an object with a main beam's band at the
    start, or None."""
    s, p, h = (np.asarray(x) for x in main_beam_samples(finger, samples))
    gap = np.asarray(obj.signed_distance(p)) - h
    worst = None
    for b, name in ((FRONT, "front"), (BACK, "back")):
        i = int(np.argmin(gap[b]))
        if gap[b, i] < 0 and (worst is None or -gap[b, i] > worst[2]):
            worst = (name, float(s[b, i]), float(-gap[b, i]))
    return worst
