"""Shared pieces of the optimize/ scripts: the example finger, grasps with a fixed contact
law, and the contact force with its derivative in one design value (forward mode through
`finray_jax.regrasp`, warm started from the last equilibrium)."""

from __future__ import annotations

import csv
import dataclasses
import json
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp

import finray_jax as fr
from finray_jax import io as fio

CLOSING = 6.0  # mm


def finger_text() -> str:
    """Finger-1 (assumed dimensions; finray_jax's packaged finger1.toml, the same file as
    examples/finger1.toml) as text."""
    return fio.packaged_finger_text("finger1.toml")


def load_finger1(count: int | None = None) -> fr.Finger:
    """Finger-1, optionally with `count` evenly spaced horizontal crossbeams over the same
    span of the front beam (s = 15..105 mm), through the file's crossbeam pattern."""
    text = finger_text()
    if count is not None:
        if "count = 7" not in text:
            raise RuntimeError("finger1.toml no longer has 'count = 7'")
        text = text.replace("count = 7", f"count = {int(count)}")
    finger, _ = fio.loads_finger(text, source="finger1.toml (finray_jax data)")
    return finger


def with_stiffness(finger: fr.Finger, k: float, k_support: float | None = None) -> fr.Finger:
    """The finger with a fixed contact penalty stiffness k (N/mm^2), and the support's
    (default: the same k)."""
    contact = dataclasses.replace(
        finger.contact,
        stiffness=jnp.asarray(float(k)),
        support_stiffness=None if k_support is None else jnp.asarray(float(k_support)),
    )
    return dataclasses.replace(finger, contact=contact)


@eqx.filter_jit
def _force_and_slope(setter, base, x, ref):
    def force(x):
        sol, contact = fr.regrasp(ref, setter(base, x))
        return contact.normal_force, (sol, contact.max_penetration)

    f, df, (sol, pen) = jax.jvp(force, (x,), (jnp.ones_like(x),), has_aux=True)
    return f, df, sol, pen


class ContactForce:
    """Contact force F (N) of a grasp at fixed closing and its derivative dF/dx in one
    design value x, set by `setter(base_finger, x)`.

    Every design is solved by `regrasp` from the equilibrium of the last design (one
    compiled program per finger topology); when that Newton solve does not converge (too
    long a step) the design is grasped from scratch and the solve repeated. The contact
    stiffness must be fixed in the finger (`with_stiffness`) so that every design is
    judged by the same contact law (`grasp(..., stiffen=False)`).
    """

    def __init__(self, setter, closing: float = CLOSING):
        self.setter = setter
        self.closing = closing
        # the first GraspSolution of each topology: fixes the static fields. (The contact
        # problem's subdivision of the beams depends on the attachment points, so a
        # design value such as a crossbeam angle can change the topology of a fresh
        # grasp.)
        self.templates = {}
        self.grasps = 0
        self.solves = 0

    def grasp(self, base: fr.Finger, x: float) -> fr.GraspSolution:
        self.grasps += 1
        g = fr.grasp(self.setter(base, jnp.asarray(float(x))), self.closing, stiffen=False)
        if not g.converged:
            raise RuntimeError(f"grasp failed at x = {x}: {g.status}")
        template = self.templates.setdefault(g.topology, g)
        # same static fields as the template: the compiled regrasp is reused
        return eqx.tree_at(
            lambda r: (r.solution, r.closing, r.stiffness, r.support_stiffness),
            template,
            (g.solution, g.closing, g.stiffness, g.support_stiffness),
        )

    def __call__(self, base: fr.Finger, x: float, ref=None):
        """(F, dF/dx, ref at x, max penetration); ref=None grasps from scratch."""
        if ref is None:
            ref = self.grasp(base, x)
        self.solves += 1
        f, df, sol, pen = _force_and_slope(self.setter, base, jnp.asarray(float(x)), ref)
        if sol.result != fr.RESULTS.successful:
            ref = self.grasp(base, x)
            self.solves += 1
            f, df, sol, pen = _force_and_slope(self.setter, base, jnp.asarray(float(x)), ref)
            if sol.result != fr.RESULTS.successful:
                raise RuntimeError(f"regrasp failed at x = {x}: {fr.RESULTS[sol.result]}")
        return float(f), float(df), eqx.tree_at(lambda r: r.solution, ref, sol), float(pen)


def write_csv(path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def write_json(path, data) -> None:
    pathlib.Path(path).write_text(json.dumps(data, indent=2, allow_nan=True))


def print_table(rows: list[dict], formats: dict) -> None:
    head = list(formats)
    cells = [[formats[k].format(r[k]) for k in head] for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(head)]
    print("  ".join(h.rjust(w) for h, w in zip(head, widths)))
    for c in cells:
        print("  ".join(x.rjust(w) for x, w in zip(c, widths)))
