"""Named design values and named scalar outputs of a finger, for sweeps and optimisation.

This module sits on the public API (like `io`): it gives the continuous design values of a
`Finger` and the scalar outputs of a `Solution` short names, so batches, sweep files and
optimisers can refer to them. Everything here is traceable: `set_design` and the outputs
run under `jit`, `vmap` and `grad`. The physics core never imports it.

Design values (`DESIGN_VALUES`; units mm, MPa, rad):

    material.E, material.nu
    front.thickness, back.thickness, front.depth, back.depth
    depth                         every depth: front, back and all crossbeams (reads front)
    adaptor.front_clamp_length, adaptor.back_clamp_length
    adaptor.support_length        l_s of the modified adaptor (needs a support in the finger)
    tip.x, tip.z                  the shared tip point (attachment arc lengths stay put)
    front.curvature, back.curvature
    crossbeams.front_s, crossbeams.back_s, crossbeams.thickness, crossbeams.depth
    crossbeams.angle              see below

A crossbeam name without an index is the whole array (shape (C,)); `name[i]` is crossbeam
i (numbered from 0). `crossbeams.angle[i]` is the angle (rad) of crossbeam i's undeformed
centreline to the horizontal (+x): atan2(dz, dx) of the vector from its front-beam end to
its back-beam end, positive when the back end lies higher. Setting it keeps front_s[i] and
moves the back attachment back_s[i] along the back beam to where the ray from the front
end at that angle meets it. In `set_design`, angles are applied last, at the final
geometry (after front_s, tip, ...); all other names in the order given.

Outputs (`OUTPUTS`, name -> fn(solution, finger) -> scalar; extend with `register_output`):

    tip.dx, tip.dy, tip.dz        tip displacement (mm)
    tip.x, tip.z                  deformed tip position (mm)
    tip.rotation                  tip rotation about y (rad)
    reaction.front.fx ... .mz     wrench the adaptor applies to the front beam at its base
    reaction.back.fx ... .mz      (N, N mm; moment about the base point)
    load_factor                   1 when converged; the fold factor beyond the limit load
    max_strain                    largest |n3| / EA + |m2| c / EI2 over both main beams
    max_strain.front, max_strain.back

Outputs of a grasp (`GRASP_OUTPUTS`, name -> fn(GraspSolution) -> scalar):

    contact.normal_force          normal contact force on one finger (N)
    contact.force.x, .z           total contact force on the finger (N)
    contact.length                arc length in contact (mm)
    contact.max_penetration       largest penetration into an object (mm)
    contact.support_force.x, .z   force of the adaptor's support on the back beam (N)
    contact.support_penetration   largest penetration of the back beam into the support (mm)
    contact.crossbeam_force.x, .z mean crossbeam force on the front beam (N; Fig. 4)
    actuator_force                force of the actuator along the closing direction (N)
    closing                       the closing displacement (mm)

Outputs of the grasp's release trace (`RELEASE_OUTPUTS`, name -> fn(ReleaseTrace) -> scalar;
`finray_jax.release_force`):

    release.peak                  holding force: the largest pull the grasp resists (N, all
                                  fingers)
    release.peak_pull             the pull distance at that peak (mm)
    release.complete              1 when the trace reached the loss of contact, else 0 (it
                                  stopped early: its peak is the largest force up to there)
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Callable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp

from ._finger import BACK, FRONT, Finger
from ._geometry import arc_point, geometry, thickness_at
from ._rules import GEOMETRY_RULES, rules_hold
from ._segment_table import segment_table  # (the solver's own segment lengths)
from ._types import as_float

__all__ = [
    "DESIGN_VALUES",
    "OUTPUTS",
    "GRASP_OUTPUTS",
    "RELEASE_OUTPUTS",
    "DesignError",
    "check_design_names",
    "check_output_names",
    "design_valid_jit",
    "design_names",
    "design_valid",
    "evaluate_outputs",
    "geometry_valid",
    "get_design",
    "main_beam_strain",
    "register_output",
    "set_design",
]


class DesignError(ValueError):
    """An unknown or misused design value or output name."""


# --------------------------------------------------------------------------------------
# Design values
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DesignValue:
    """How to read and write one named design value.

    get(finger) -> array; set(finger, value) -> finger (value of the same shape).
    per_crossbeam: the value is a (C,) array and `name[i]` addresses crossbeam i.
    """

    get: Callable
    set: Callable
    per_crossbeam: bool = False


def _leaf(where: Callable) -> tuple[Callable, Callable]:
    return where, lambda f, v: eqx.tree_at(where, f, as_float(v))


def _all_depths(f: Finger, v) -> Finger:
    v = as_float(v)
    return eqx.tree_at(
        lambda g: (g.front.depth, g.back.depth, g.crossbeams.depth),
        f,
        (v, v, jnp.broadcast_to(v, jnp.shape(f.crossbeams.depth))),
    )


def _tip(k: int) -> tuple[Callable, Callable]:
    get = lambda f: f.tip[k]
    return get, lambda f, v: eqx.tree_at(lambda g: g.tip, f, f.tip.at[k].set(as_float(v)))


def crossbeam_angle(finger: Finger):
    """(C,) angle of every crossbeam to the horizontal (rad), front end to back end."""
    geo = geometry(finger)
    d = arc_point(geo.base[BACK], geo.theta[BACK], geo.curvature[BACK], finger.crossbeams.back_s)
    d = d - geo.base[2:]
    return jnp.arctan2(d[:, 2], d[:, 0])


def _back_s_for_angle(finger: Finger, angle, newton_steps: int = 6):
    """Back-beam arc lengths where rays from the crossbeams' front ends at `angle` meet the
    back beam. Newton on the cross product, started at the current back_s: exact after one
    step for a straight back beam, converging quadratically on an arc (and so do its
    derivatives, as the steps are unrolled)."""
    geo = geometry(finger)
    base, theta, kappa = geo.base[BACK], geo.theta[BACK], geo.curvature[BACK]
    front = geo.base[2:]
    e = jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)  # (x, z)
    s = finger.crossbeams.back_s
    for _ in range(newton_steps):
        d = arc_point(base, theta, kappa, s) - front
        g = d[:, 0] * e[:, 1] - d[:, 2] * e[:, 0]
        phi = theta + kappa * s
        dg = jnp.sin(phi) * e[:, 1] - jnp.cos(phi) * e[:, 0]
        s = s - g / dg
    return s


def _set_angle(f: Finger, v) -> Finger:
    v = jnp.broadcast_to(as_float(v), jnp.shape(f.crossbeams.back_s))
    return eqx.tree_at(lambda g: g.crossbeams.back_s, f, _back_s_for_angle(f, v))


def _support_get(f: Finger):
    if f.adaptor.support_length is None:
        raise DesignError(
            "design value 'adaptor.support_length': this finger's adaptor has no support "
            "(set adaptor.support_length in the finger first)"
        )
    return f.adaptor.support_length


def _support_set(f: Finger, v) -> Finger:
    _support_get(f)
    return eqx.tree_at(lambda g: g.adaptor.support_length, f, as_float(v))


DESIGN_VALUES: dict[str, DesignValue] = {
    "material.E": DesignValue(*_leaf(lambda f: f.material.E)),
    "material.nu": DesignValue(*_leaf(lambda f: f.material.nu)),
    "front.thickness": DesignValue(*_leaf(lambda f: f.front.thickness)),
    "back.thickness": DesignValue(*_leaf(lambda f: f.back.thickness)),
    "front.depth": DesignValue(*_leaf(lambda f: f.front.depth)),
    "back.depth": DesignValue(*_leaf(lambda f: f.back.depth)),
    "depth": DesignValue(lambda f: f.front.depth, _all_depths),
    "adaptor.front_clamp_length": DesignValue(*_leaf(lambda f: f.adaptor.front_clamp_length)),
    "adaptor.back_clamp_length": DesignValue(*_leaf(lambda f: f.adaptor.back_clamp_length)),
    "adaptor.support_length": DesignValue(_support_get, _support_set),
    "tip.x": DesignValue(*_tip(0)),
    "tip.z": DesignValue(*_tip(1)),
    "front.curvature": DesignValue(*_leaf(lambda f: f.front_curvature)),
    "back.curvature": DesignValue(*_leaf(lambda f: f.back_curvature)),
    "crossbeams.front_s": DesignValue(*_leaf(lambda f: f.crossbeams.front_s), True),
    "crossbeams.back_s": DesignValue(*_leaf(lambda f: f.crossbeams.back_s), True),
    "crossbeams.thickness": DesignValue(*_leaf(lambda f: f.crossbeams.thickness), True),
    "crossbeams.depth": DesignValue(*_leaf(lambda f: f.crossbeams.depth), True),
    "crossbeams.angle": DesignValue(crossbeam_angle, _set_angle, True),
}

_NAME = re.compile(r"(?P<base>[A-Za-z_][\w.]*)(?:\[(?P<index>-?\d+)\])?")


def design_names(finger: Finger | None = None, *, scalar: bool = False) -> list[str]:
    """Valid design-value names (indexed ones as `name[i]` with the valid range of i).
    scalar: only names of one number (a per-crossbeam value only with its index)."""
    n = None if finger is None else finger.n_crossbeams
    out = []
    for name, dv in DESIGN_VALUES.items():
        if not (scalar and dv.per_crossbeam):
            out.append(name)
        if dv.per_crossbeam:
            out.append(f"{name}[i]" if n is None else f"{name}[0..{n - 1}]")
    return out


def _alike(name: str, typed: str) -> bool:
    """Whether a suggested name's last part is close to the typed one's too (a shared
    prefix alone, as in crossbeams.foo and crossbeams.front_s, is no likeness)."""
    last = lambda n: n.rsplit(".", 1)[-1].lower()
    return difflib.SequenceMatcher(None, last(name), last(typed)).ratio() >= 0.6


def _parse(name, finger: Finger, scalar: bool = False) -> tuple[DesignValue, int | None]:
    m = _NAME.fullmatch(name) if isinstance(name, str) else None
    dv = DESIGN_VALUES.get(m["base"]) if m else None
    if dv is None:
        base = m["base"] if m else str(name)
        close = [
            c
            for c in difflib.get_close_matches(base, DESIGN_VALUES, cutoff=0.75)
            if _alike(c, base)
        ]
        index = f"[{m['index']}]" if m and m["index"] is not None else ""
        hint = f" (did you mean '{close[0]}{index}'?)" if close else ""
        valid = ", ".join(design_names(finger, scalar=scalar))
        raise DesignError(f"unknown design value {name!r}{hint}; valid names: {valid}")
    if m["index"] is None:
        return dv, None
    i, n = int(m["index"]), finger.n_crossbeams
    if not dv.per_crossbeam:
        raise DesignError(f"design value {m['base']!r} takes no index, got {name!r}")
    if not 0 <= i < n:
        raise DesignError(
            f"design value {name!r}: no crossbeam {i}; this finger has {n} crossbeams "
            f"(indices 0..{n - 1})"
        )
    return dv, i


def check_design_names(finger: Finger, names, *, scalar: bool = False) -> None:
    """Raise DesignError for an unknown name (or, with scalar=True, a whole-array name)."""
    for name in names:
        dv, i = _parse(name, finger, scalar)
        if scalar and dv.per_crossbeam and i is None:
            raise DesignError(
                f"design value {name!r} is an array of {finger.n_crossbeams} numbers; give one "
                f"crossbeam, e.g. {name}[0]"
            )


def get_design(finger: Finger, names) -> dict[str, jax.Array]:
    """The current values of the named design values."""
    out = {}
    for name in names:
        dv, i = _parse(name, finger)
        v = dv.get(finger)
        out[name] = v if i is None else v[i]
    return out


def set_design(finger: Finger, values: Mapping[str, jax.typing.ArrayLike]) -> Finger:
    """A copy of `finger` with the named design values replaced (traceable: values may be
    tracers). Crossbeam angles are applied last; everything else in the given order."""
    parsed = [(name, *_parse(name, finger)) for name in values]
    angle = DESIGN_VALUES["crossbeams.angle"]
    for name, dv, i in sorted(parsed, key=lambda p: p[1] is angle):
        v = as_float(values[name])
        if i is not None:
            v = dv.get(finger).at[i].set(v)
            if dv is angle:  # move only crossbeam i's back end
                back_s = finger.crossbeams.back_s.at[i].set(_back_s_for_angle(finger, v)[i])
                finger = eqx.tree_at(lambda g: g.crossbeams.back_s, finger, back_s)
                continue
        expected = jnp.shape(dv.get(finger))
        if jnp.shape(v) != expected:
            raise DesignError(f"design value {name!r} must have shape {expected}, got {v.shape}")
        finger = dv.set(finger, v)
    return finger


def design_valid(finger: Finger, topology) -> jax.Array:
    """Traced check that a design is valid and keeps `topology` (the order of attachments
    and load points along each beam of the finger the topology was built from): a bool
    scalar.

    Valid: every rule of `validate_finger` on design values (`_rules.RULES`, written once
    for both): finite values, positive stiffnesses and lengths, attachments inside their
    beams and in order, the adaptor's rules (clamps inside their beams, on clamped bases
    of straight beams only; the support from the end of the back beam's clamp to at most
    its length, behind a straight back beam), and the geometry rules (`geometry_valid`).
    The loads, the contact model and the objects are the base finger's, checked eagerly.
    """
    geo = geometry(finger)
    table = segment_table(topology, finger, geo)
    return rules_hold(finger, geo) & jnp.all(table.length >= 0.0)


# design_valid compiled once per topology, for eager callers (a batch's or optimiser's
# check of one design at a time: run eagerly, its many small operations would each be
# dispatched on their own).
design_valid_jit = eqx.filter_jit(design_valid)


@jax.jit  # eager calls (the optimiser's check of a step) compile once, not every time
def geometry_valid(finger: Finger, geo=None) -> jax.Array:
    """The geometry rules of `validate_finger` (see docs/finger-format.md, "Geometry
    rules"), traced, a bool scalar: each base at least half the front plus half the back
    thickness from the other beam's centreline; the undeformed centrelines never crossing
    before the tip and that far apart outside the exempt zone at the tip; every crossbeam
    at least half the sum of the main beams' half thicknesses at its ends long."""
    return rules_hold(finger, geo, GEOMETRY_RULES)


# --------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------


def main_beam_strain(sol, finger: Finger, beam: int):
    """Axial plus bending strain |n3| / EA + |m2| c / EI2 (c = thickness / 2) at every
    solution point of a main beam, 0 inside the adaptor's clamped length."""
    bs = sol.front if beam == FRONT else sol.back
    sec = finger.front if beam == FRONT else finger.back
    clamp = (finger.adaptor.front_clamp_length, finger.adaptor.back_clamp_length)[beam]
    t = thickness_at(sec, bs.s, geometry(finger).length[beam])
    E, d = finger.material.E, sec.depth
    n3 = jnp.einsum("ni,ni->n", bs.force, bs.frame[:, :, 2])
    m2 = jnp.einsum("ni,ni->n", bs.moment, bs.frame[:, :, 1])
    strain = jnp.abs(n3) / (E * t * d) + jnp.abs(m2) * 6.0 / (E * d * t**2)
    inside = bs.s < clamp - 1e-9 * geometry(finger).L
    return jnp.where(inside, 0.0, strain)


def _max_strain(sol, finger):
    return jnp.maximum(
        jnp.max(main_beam_strain(sol, finger, FRONT)), jnp.max(main_beam_strain(sol, finger, BACK))
    )


OUTPUTS: dict[str, Callable] = {
    "tip.dx": lambda sol, f: sol.tip.displacement[0],
    "tip.dy": lambda sol, f: sol.tip.displacement[1],
    "tip.dz": lambda sol, f: sol.tip.displacement[2],
    "tip.x": lambda sol, f: sol.tip.position[0],
    "tip.z": lambda sol, f: sol.tip.position[2],
    "tip.rotation": lambda sol, f: sol.tip.rotation[1],
    "load_factor": lambda sol, f: sol.load_factor,
    "max_strain": _max_strain,
    "max_strain.front": lambda sol, f: jnp.max(main_beam_strain(sol, f, FRONT)),
    "max_strain.back": lambda sol, f: jnp.max(main_beam_strain(sol, f, BACK)),
}
for _beam in ("front", "back"):
    for _k, _c in enumerate("xyz"):
        OUTPUTS[f"reaction.{_beam}.f{_c}"] = lambda sol, f, b=_beam, k=_k: getattr(
            sol, f"reactions_{b}"
        ).force[k]
        OUTPUTS[f"reaction.{_beam}.m{_c}"] = lambda sol, f, b=_beam, k=_k: getattr(
            sol, f"reactions_{b}"
        ).moment[k]


# Outputs of a grasp (`finray_jax.grasp`), name -> fn(GraspSolution) -> scalar: the contact
# of one finger with its objects. (A grasp's equilibrium also has every output above.)
GRASP_OUTPUTS: dict[str, Callable] = {
    "contact.normal_force": lambda g: g.contact.normal_force,
    "contact.force.x": lambda g: g.contact.force[0],
    "contact.force.z": lambda g: g.contact.force[2],
    "contact.length": lambda g: g.contact.contact_length,
    "contact.max_penetration": lambda g: g.contact.max_penetration,
    "contact.support_force.x": lambda g: g.contact.support_force[0],
    "contact.support_force.z": lambda g: g.contact.support_force[2],
    "contact.support_penetration": lambda g: g.contact.support_penetration,
    "contact.crossbeam_force.x": lambda g: g.contact.crossbeam_force[0],
    "contact.crossbeam_force.z": lambda g: g.contact.crossbeam_force[2],
    "actuator_force": lambda g: g.contact.actuator_force,
    "closing": lambda g: g.closing,
}

# Outputs of a grasp's release trace (`finray_jax.release_force`), name -> fn(ReleaseTrace).
RELEASE_OUTPUTS: dict[str, Callable] = {
    "release.peak": lambda tr: tr.peak,
    "release.peak_pull": lambda tr: tr.peak_pull,
    "release.complete": lambda tr: float(tr.complete),
}


def register_output(name: str, fn: Callable, *, replace: bool = False) -> None:
    """Add a named scalar output fn(solution, finger) -> scalar (traceable)."""
    if not isinstance(name, str) or not name or "," in name:
        raise DesignError(f"an output name must be a non-empty string without commas: {name!r}")
    if name in OUTPUTS and not replace:
        raise DesignError(f"output {name!r} exists already (pass replace=True to replace it)")
    OUTPUTS[name] = fn


def check_output_names(names) -> None:
    for name in names:
        if name not in OUTPUTS:
            raise DesignError(f"unknown output {name!r}; valid outputs: {', '.join(OUTPUTS)}")


def evaluate_outputs(sol, finger: Finger, names) -> dict[str, jax.Array]:
    """The named scalar outputs of a solution (traceable)."""
    check_output_names(names)
    return {name: jnp.asarray(OUTPUTS[name](sol, finger), dtype=jnp.float64) for name in names}
