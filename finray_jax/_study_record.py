"""The record of a study (a JSON file beside its results): the study's hash (its finger
and settings), read back so that an interrupted study goes on from what it finished, and
rewritten atomically after every finished piece; release traces as JSON."""

import hashlib
import json
import os

import jax
import numpy as np

from . import io as fio
from ._finger import Finger
from ._release import ReleaseTrace


class StudyRecordError(ValueError):
    """A study's record file that cannot be read as one (the CLI reports it, no traceback)."""


# Bump when a record would mean something else (it keys the records' hashes).
_RECORD_VERSION = 1


def finger_digest(finger: Finger) -> str:
    """A hash of everything a finger holds (structure, settings and values), the same in
    every process: two fingers with the same digest solve alike. (Any pytree will do.)"""
    leaves, treedef = jax.tree_util.tree_flatten(finger)
    h = hashlib.sha256(str(treedef).encode())
    for leaf in leaves:
        a = np.asarray(leaf)
        h.update(f"{a.dtype}{a.shape}".encode() + a.tobytes())
    return h.hexdigest()


def study_hash(kind: str, finger: Finger, settings: dict) -> str:
    """The hash that keys a study's record: its kind, finger and settings."""
    key = {"kind": kind, "version": _RECORD_VERSION, "finger": finger_digest(finger), **settings}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


def read_record(path, digest, kind, say):
    """The record of the study `digest` kept in `path` (a dict), or None when the file is
    missing or holds another study (said). A file that is no JSON object is refused."""
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            rec = json.load(fh)
        if not isinstance(rec, dict):
            raise ValueError("not a JSON object")
        if "study_hash" not in rec:
            raise ValueError("a JSON object without a study_hash")
    except (OSError, ValueError) as exc:
        raise StudyRecordError(
            f"{path}: not a {kind} record ({exc}); move it away to start afresh"
        ) from None
    if rec.get("study_hash") != digest:
        say(f"{path} holds another study (finger or settings differ): starting afresh")
        return None
    return rec


def write_record(path, rec: dict) -> None:
    """Rewrite a study's record atomically (an interruption leaves the old or the new)."""
    parent = os.path.dirname(path)
    if parent:
        os.makedirs(parent, exist_ok=True)
    fio.write_atomic(path, fio.json_text(fio.to_plain(rec)) + "\n")


def trace_record(t: ReleaseTrace) -> dict:
    """A release trace as a record's JSON object."""
    names = ("pull", "force", "normal_force", "peak", "peak_pull", "complete", "message")
    return {k: getattr(t, k) for k in names}


def trace_from_record(t: dict) -> ReleaseTrace:
    """The release trace a record's JSON object holds."""
    num = lambda x: np.nan if x is None else float(x)  # (JSON keeps NaN as null)
    arr = lambda x: np.asarray([np.nan if v is None else v for v in x], dtype=float)
    return ReleaseTrace(
        pull=arr(t["pull"]),
        force=arr(t["force"]),
        normal_force=arr(t["normal_force"]),
        peak=num(t["peak"]),
        peak_pull=num(t["peak_pull"]),
        complete=bool(t["complete"]),
        message=str(t["message"]),
    )
