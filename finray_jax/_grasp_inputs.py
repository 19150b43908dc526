"""A grasp's inputs: the checks of the finger, its objects and a direction, and the edits
a grasp's paths make to the finger (objects moved, contact values replaced)."""

import dataclasses

import equinox as eqx
import numpy as np

from ._errors import FingerError
from ._finger import Finger, validate_finger
from ._geometry import main_beam_samples
from ._types import as_float


def unit_direction(direction, name):
    """The (x, z) direction as a unit vector; `name` is the argument's, for the error."""
    w = np.asarray(direction, dtype=np.float64)
    if w.shape != (2,) or not np.all(np.isfinite(w)) or np.linalg.norm(w) == 0:
        raise FingerError(f"{name} must be a non-zero (x, z) direction, got {w.tolist()}")
    return w / np.linalg.norm(w)


def check_objects(finger: Finger, w):
    """The finger is valid (this is the grasp's one validation); its objects lie ahead of
    its front side and within its span."""
    if not isinstance(finger, Finger):
        raise TypeError(f"expected a Finger, got {type(finger).__name__}")
    if not finger.objects:
        raise FingerError("grasp needs at least one object (Finger.objects is empty)")
    validate_finger(finger)
    pts = np.asarray(main_beam_samples(finger, 201)[1]).reshape(-1, 2)
    across = np.array([-w[1], w[0]])
    lo, hi = np.min(pts @ across), np.max(pts @ across)
    for i, obj in enumerate(finger.objects):
        if obj.kind == "half_plane":
            continue
        out = obj.outline(400)
        a, b = np.min(out @ across), np.max(out @ across)
        if b < lo or a > hi:
            raise FingerError(
                f"objects[{i}] ({obj.kind}) is outside the reach of the finger: it spans "
                f"[{a:.4g}, {b:.4g}] mm across the closing direction, the finger [{lo:.4g}, "
                f"{hi:.4g}] mm"
            )
        if np.max(out @ w) < np.min(pts @ w):
            raise FingerError(
                f"objects[{i}] ({obj.kind}) lies behind the finger: closing along "
                f"{w.tolist()} moves the finger away from it"
            )


def with_objects_moved(finger: Finger, displacement) -> Finger:
    """The finger with every object moved by `displacement` (x, z)."""
    # (dataclasses.replace: half the cost of eqx.tree_at, which a path pays per step)
    objs = tuple(o.moved(displacement) for o in finger.objects)
    return dataclasses.replace(finger, objects=objs)


def with_contact(finger: Finger, **values) -> Finger:
    """The finger with the given fields of its Contact replaced (as float arrays)."""
    c = finger.contact
    for key, v in values.items():
        c = eqx.tree_at(
            lambda c, key=key: getattr(c, key), c, as_float(v), is_leaf=lambda x: x is None
        )
    return eqx.tree_at(lambda f: f.contact, finger, c)


def with_stiffness(finger: Finger, k, k_support=None, k_members=None) -> Finger:
    """The finger with the objects' penalty stiffness k, the support's and the members'
    (default: the ones it has)."""
    values = {"stiffness": k, "support_stiffness": k_support, "member_stiffness": k_members}
    return with_contact(finger, **{key: v for key, v in values.items() if v is not None})
