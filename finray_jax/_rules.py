"""A finger's validity rules, written once as traced checks.

Each `Rule` is a traced check of the finger (and its geometry) that returns where it holds
(a bool scalar, or a bool per crossbeam or per pair of neighbouring crossbeams) and the
values its message names. The same table serves both sides:

- traced (`rules_hold`): the AND of every rule, under `jit`, `vmap` and `grad`; a batch,
  sweep or optimiser step marks a design that breaks one invalid (`design.design_valid`);
- eager (`broken_rule`): every rule evaluated at once on a concrete finger, compiled; the
  message of the first rule that fails, at its first failing index, names the field and
  the value (`validate_finger` raises it).

`RULES` is in the order the eager check reports them. Checks that are not values of a
design (shapes, types, finiteness of each field, the loads, the contact model and the
objects) are eager only (`_checks`, `_finger.validate_finger`).
"""

import dataclasses
import types
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._centrelines import BACK, FRONT, Clearance, clearance
from ._geometry import geometry, xz


class Context(NamedTuple):
    """What a rule's check reads: the finger, its geometry and its main beams' clearance."""

    finger: object
    geo: object
    gap: Clearance


class Check(NamedTuple):
    """A rule's verdict: `ok` (bool, scalar or one per item) where the rule holds, and the
    values its message names (arrays, or static strings)."""

    ok: jax.Array
    values: dict


@dataclasses.dataclass(frozen=True)
class Rule:
    """One validity rule. check(context) -> Check; message(values, i) -> the error, with
    the values (numpy) as attributes and i the first failing index (None for a scalar
    rule). geometry: one of the geometry rules (`geometry_valid`)."""

    check: Callable[[Context], Check]
    message: Callable[[types.SimpleNamespace, int | None], str]
    geometry: bool = False


def _true():
    return jnp.array(True)


def _fmt(p) -> str:
    """A point (x, z) to 4 digits (round-off below 1e-9 mm shown as 0)."""
    return "(" + ", ".join(f"{round(float(x), 9) + 0.0:.4g}" for x in p) + ")"


# --------------------------------------------------------------------------------------
# Values: finite, positive, in range
# --------------------------------------------------------------------------------------


def _finite(c: Context) -> Check:
    leaves = [x for x in jax.tree_util.tree_leaves(c.finger) if eqx.is_array(x)]
    return Check(jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves])), {})


def _positive(field: str, get: Callable) -> Rule:
    """`field` (with `{i}` for a per-crossbeam value) must be positive; get(finger) reads
    it (None: the finger has no such value, and the rule holds)."""

    def check(c):
        x = get(c.finger)
        return Check(_true(), {}) if x is None else Check(x > 0, {"x": x})

    def message(v, i):
        x = v.x if i is None else v.x[i]
        return f"{field.format(i=i)} must be positive, got {x}"

    return Rule(check, message)


def _nu(c):
    nu = c.finger.material.nu
    return Check((nu > -1.0) & (nu < 0.5), {"nu": nu})


def _chord(name: str) -> Rule:
    """A main beam's precurvature: at most a near half circle over its chord."""

    def check(c):
        f = c.finger
        kappa, base = getattr(f, f"{name}_curvature"), getattr(f, f"{name}_base")
        chord = jnp.linalg.norm(xz(f.tip) - xz(base))
        return Check(jnp.abs(kappa) * chord / 2.0 < 0.99, {"kappa": kappa, "chord": chord})

    def message(v, i):
        return (
            f"{name}_curvature = {v.kappa} is too large for a chord of {v.chord:.6g} mm: "
            f"|curvature| * chord / 2 must stay below 0.99 (at most a near half circle)"
        )

    return Rule(check, message)


def _has_length(beam: int, name: str) -> Rule:
    def check(c):
        return Check(c.geo.length[beam] > 0, {"tip": c.finger.tip})

    def message(v, i):
        return f"{name} beam has zero length: {name}_base equals tip {v.tip}"

    return Rule(check, message)


def _bases_apart(c):
    return Check(jnp.any(c.finger.front_base != c.finger.back_base), {})


VALUE_RULES = (
    Rule(_finite, lambda v, i: "every value of the finger must be finite"),
    _positive("material.E", lambda f: f.material.E),
    Rule(_nu, lambda v, i: f"material.nu must lie in (-1, 0.5), got {v.nu}"),
    _positive("material.shear_coefficient", lambda f: f.material.shear_coefficient),
    *(
        _positive(f"{beam}.{field}", lambda f, b=beam, k=field: getattr(getattr(f, b), k))
        for beam in ("front", "back")
        for field in ("thickness", "tip_thickness", "depth")
    ),
    _chord("front"),
    _chord("back"),
    _has_length(FRONT, "front"),
    _has_length(BACK, "back"),
    # (Coincident bases also break `_base_clear` below; this names the mistake.)
    Rule(_bases_apart, lambda v, i: "front_base and back_base coincide"),
)


# --------------------------------------------------------------------------------------
# Geometry: main beams apart except at their tip, never crossing
# --------------------------------------------------------------------------------------


def _fields(v) -> str:
    """The fields that place the main beams, for the geometry rules' messages."""
    out = (
        f"front_base = {v.front_base.tolist()}, back_base = {v.back_base.tolist()}, "
        f"tip = {v.tip.tolist()}"
    )
    for name in ("front_curvature", "back_curvature"):
        kappa = float(getattr(v, name))
        if kappa != 0.0:
            out += f", {name} = {kappa}"
    return out


def _placing(f) -> dict:
    names = ("front_base", "back_base", "tip", "front_curvature", "back_curvature")
    return {name: getattr(f, name) for name in names}


def _base_clear(own: int) -> Rule:
    """A base at least half its beam's plus half the other beam's thickness from the
    other beam's centreline."""
    own_name, other_name = ("front", "back") if own == FRONT else ("back", "front")

    def check(c):
        g, lines = c.gap, c.gap.lines
        d, s, least = g.distance[own, 0], g.other_s[own, 0], g.least[own, 0]
        values = {
            "base": lines.p[own, 0],
            "d": d,
            "s": s,
            "least": least,
            "own_t": 2.0 * lines.half(0.0, own),
            "other_t": 2.0 * lines.half(s, 1 - own),
            "tol": 1e-9 * jnp.max(lines.length),
        }
        return Check(d >= least, values)

    def message(v, i):
        where = "on" if v.d <= v.tol else f"{v.d:.4g} mm from"
        return (
            f"{own_name}_base = {v.base.tolist()} lies {where} the {other_name} beam's "
            f"centreline (nearest at {other_name} s = {v.s:.4g}): it must lie at least "
            f"{v.least:.4g} mm from it (half of {own_name}.thickness = {v.own_t:.4g} mm at "
            f"the base plus half of {other_name}.thickness = {v.other_t:.4g} mm there), or "
            "the two beams overlap; they may meet only at the tip"
        )

    return Rule(check, message, geometry=True)


def _no_crossing(c):
    x = c.gap.crossing
    values = {"point": x.point, "sb": x.back_s, "sf": x.front_s, **_placing(c.finger)}
    return Check(~x.crosses, values)


def _crossing_message(v, i):
    return (
        f"the back beam crosses the front beam at (x, z) = {_fmt(v.point)} (back s = "
        f"{v.sb:.4g}, front s = {v.sf:.4g}): the two beams may meet only at the tip "
        f"({_fields(v)})"
    )


def _apart(c):
    """The centrelines at least the two half thicknesses apart outside the tip's zone;
    the values are those of the worst sample (the back beam's first at a tie)."""
    g, lines = c.gap, c.gap.lines
    ratio = g.distance / g.least
    ok = ~jnp.any(g.outside_zone & (ratio < 1.0))
    n = ratio.shape[1]
    k = jnp.argmin(jnp.where(g.outside_zone, ratio, jnp.inf)[::-1].ravel())
    own, j = jnp.where(k < n, BACK, FRONT), k % n
    s_own, s_other = lines.s[own, j], g.other_s[own, j]
    point = lines.p[own, j]
    values = {
        "d": g.distance[own, j],
        "least": g.least[own, j],
        "sf": jnp.where(own == FRONT, s_own, s_other),
        "sb": jnp.where(own == FRONT, s_other, s_own),
        "point": point,
        "from_tip": jnp.linalg.norm(point - c.finger.tip),
        "zone": g.zone,
        **_placing(c.finger),
    }
    return Check(ok, values)


def _apart_message(v, i):
    return (
        f"the front and back beams' centrelines come within {v.d:.4g} mm of each other "
        f"at front s = {v.sf:.4g}, back s = {v.sb:.4g} (near (x, z) = {_fmt(v.point)}, "
        f"{v.from_tip:.4g} mm from the tip): apart from the last {v.zone:.4g} mm before the "
        f"tip they must stay at least {v.least:.4g} mm apart (half the front plus half the "
        f"back thickness there), or the beams overlap ({_fields(v)})"
    )


MAIN_BEAM_RULES = (
    _base_clear(BACK),  # (the one that matters in practice; the front base's mirrors it)
    _base_clear(FRONT),
    Rule(_no_crossing, _crossing_message, geometry=True),
    Rule(_apart, _apart_message, geometry=True),
)


# --------------------------------------------------------------------------------------
# Crossbeams: sections, attachments inside their beams and in order, long enough
# --------------------------------------------------------------------------------------


def _inside(beam: int, name: str) -> Rule:
    """Crossbeam attachments strictly inside their main beam."""

    def check(c):
        s, length = getattr(c.finger.crossbeams, f"{name}_s"), c.geo.length[beam]
        return Check((s > 0) & (s < length), {"s": s, "length": length})

    def message(v, i):
        return (
            f"crossbeams[{i}].{name}_s = {v.s[i]} lies outside the {name} beam (0, {v.length:.6g})"
        )

    return Rule(check, message)


def _steps(c):
    cb = c.finger.crossbeams
    return jnp.diff(cb.front_s), jnp.diff(cb.back_s), {"fs": cb.front_s, "bs": cb.back_s}


def _not_crossing(c):
    """Neighbouring crossbeams' attachments step the same way along both beams."""
    df, db, values = _steps(c)
    return Check(((df > 0) & (db > 0)) | ((df < 0) & (db < 0)), values)


def _cross_message(v, i):
    return (
        f"crossbeams {i} and {i + 1} cross or touch: front_s {v.fs[i]} -> {v.fs[i + 1]}, "
        f"back_s {v.bs[i]} -> {v.bs[i + 1]} (list crossbeams in increasing front_s, "
        "with back_s increasing too)"
    )


def _footprints(c, beam: int, name: str):
    """Crossbeams' half widths along main beam `beam` where they meet it: half the
    thickness over the sine of the angle between crossbeam and beam."""
    cb, geo = c.finger.crossbeams, c.geo
    s = getattr(cb, f"{name}_s")
    along = geo.theta[beam] + geo.curvature[beam] * s  # the main beam's tangent angle
    sine = jnp.abs(jnp.sin(geo.theta[2:] - along))
    return s, 0.5 * cb.thickness / jnp.maximum(sine, 1e-12)


def _apart_at(beam: int, name: str) -> Rule:
    """Neighbouring crossbeams' footprints on a main beam neither overlap nor touch."""

    def check(c):
        s, half = _footprints(c, beam, name)
        need = half[:-1] + half[1:]
        values = {"s": s, "need": need, "t": c.finger.crossbeams.thickness}
        return Check(jnp.abs(jnp.diff(s)) > need, values)

    def message(v, i):
        return (
            f"crossbeams {i} and {i + 1} overlap where they meet the {name} beam: "
            f"{name}_s {v.s[i]} -> {v.s[i + 1]} is {abs(v.s[i + 1] - v.s[i]):.4g} mm apart, "
            f"their thicknesses ({v.t[i]:.4g} and {v.t[i + 1]:.4g} mm, crossbeams[{i}]."
            f"thickness and crossbeams[{i + 1}].thickness) need more than {v.need[i]:.4g} "
            "mm along that beam"
        )

    return Rule(check, message)


def _base_to_tip(c):
    df, _, values = _steps(c)
    return Check(df >= 0, values)


def _order_message(v, i):
    return (
        f"crossbeams must be listed base to tip: crossbeams[{i + 1}].front_s = "
        f"{v.fs[i + 1]} < crossbeams[{i}].front_s = {v.fs[i]}"
    )


def _long_enough(c):
    """At least half the sum of the main beams' half thicknesses at its ends long."""
    cb, lines, length = c.finger.crossbeams, c.gap.lines, c.geo.length[2:]
    least = 0.5 * (lines.half(cb.front_s, FRONT) + lines.half(cb.back_s, BACK))
    values = {"length": length, "least": least, "fs": cb.front_s, "bs": cb.back_s}
    return Check((length >= least) & (length > 1e-9), values)


def _length_message(v, i):
    return (
        f"crossbeams[{i}] is {v.length[i]:.4g} mm long (from front_s = {v.fs[i]} to "
        f"back_s = {v.bs[i]}): a crossbeam must be at least {v.least[i]:.4g} mm long "
        "(half the sum of the main beams' half thicknesses at its ends); "
        "a shorter one joins nearly coincident points"
    )


CROSSBEAM_RULES = (
    _positive("crossbeams[{i}].thickness", lambda f: f.crossbeams.thickness),
    _positive("crossbeams[{i}].depth", lambda f: f.crossbeams.depth),
    _inside(FRONT, "front"),
    _inside(BACK, "back"),
    Rule(_not_crossing, _cross_message),
    Rule(_base_to_tip, _order_message),
    _apart_at(FRONT, "front"),
    _apart_at(BACK, "back"),
    Rule(_long_enough, _length_message, geometry=True),
)


# --------------------------------------------------------------------------------------
# Adaptor: clamps inside their beams, on clamped bases of straight beams; the support
# --------------------------------------------------------------------------------------


def _clamp_rules(beam: int, name: str) -> tuple[Rule, ...]:
    field = f"adaptor.{name}_clamp_length"

    def values(c):
        f = c.finger
        return {
            "lc": getattr(f.adaptor, f"{name}_clamp_length"),
            "length": c.geo.length[beam],
            "kappa": getattr(f, f"{name}_curvature"),
            "base": getattr(f.adaptor, f"{name}_base").name,
        }

    def inside(c):
        v = values(c)
        return Check((v["lc"] >= 0) & (v["lc"] < v["length"]), v)

    def straight(c):  # a clamp on a curved beam is not supported yet
        v = values(c)
        return Check((v["lc"] == 0) | (v["kappa"] == 0), v)

    def clamped(c):
        v = values(c)
        holds = getattr(c.finger.adaptor, f"{name}_base").holds_clamp
        return Check(_true() if holds else v["lc"] == 0, v)

    return (
        Rule(inside, lambda v, i: f"{field} must lie in [0, {v.length:.6g}), got {v.lc}"),
        Rule(
            straight,
            lambda v, i: (
                f"{field} = {v.lc} with {name}_curvature = {v.kappa}: "
                "a clamp on a curved beam is not supported yet"
            ),
        ),
        Rule(
            clamped,
            lambda v, i: f"{field} = {v.lc} needs adaptor.{name}_base = 'clamped', got {v.base!r}",
        ),
    )


def _support_inside(c):
    ad, lb = c.finger.adaptor, c.geo.length[BACK]
    if ad.support_length is None:
        return Check(_true(), {})
    ls, lc = ad.support_length, ad.back_clamp_length
    return Check((lc <= ls) & (ls <= lb), {"ls": ls, "lc": lc, "lb": lb})


def _support_message(v, i):
    return (
        f"adaptor.support_length = {v.ls} must lie in [back_clamp_length, back beam "
        f"length] = [{v.lc}, {v.lb:.6g}] (the support backs the back beam from the end "
        "of the clamp)"
    )


def _support_straight(c):
    f = c.finger
    if f.adaptor.support_length is None:
        return Check(_true(), {})
    return Check(f.back_curvature == 0, {"kappa": f.back_curvature})


ADAPTOR_RULES = (
    *_clamp_rules(FRONT, "front"),
    *_clamp_rules(BACK, "back"),
    Rule(_support_inside, _support_message),
    Rule(
        _support_straight,
        lambda v, i: (
            f"adaptor.support_length needs a straight back beam (back_curvature = {v.kappa})"
        ),
    ),
)

RULES = VALUE_RULES + MAIN_BEAM_RULES + CROSSBEAM_RULES + ADAPTOR_RULES
GEOMETRY_RULES = tuple(rule for rule in RULES if rule.geometry)


# --------------------------------------------------------------------------------------
# Evaluating the table
# --------------------------------------------------------------------------------------


def context(finger, geo=None) -> Context:
    geo = geometry(finger) if geo is None else geo
    return Context(finger, geo, clearance(finger, geo))


def _each_holds(finger, geo, rules) -> jax.Array:
    c = context(finger, geo)
    return jnp.stack([jnp.all(rule.check(c).ok) for rule in rules])


def rules_hold(finger, geo=None, rules: tuple[Rule, ...] = RULES) -> jax.Array:
    """Traced: whether the finger keeps every rule of `rules`, a bool scalar (the values
    the messages name are not used, so they drop out of the compiled code)."""
    return jnp.all(_each_holds(finger, geo, rules))


# Eagerly, whether each rule holds comes back as one small array from one compiled call
# (a finger's leaves are all arrays, so plain jax.jit takes it, with less dispatch than
# eqx.filter_jit); the values a message names are computed only for a broken rule.
_holds = jax.jit(lambda finger: _each_holds(finger, None, RULES))


@eqx.filter_jit  # (k static: one compilation per rule reported, the rest left out)
def _verdict(finger, k: int) -> Check:
    return RULES[k].check(context(finger))


def broken_rule(finger) -> str | None:
    """Eager: the message of the first rule (in `RULES` order) that a concrete finger
    breaks, at its first failing index, or None when it keeps them all. The finger's
    fields must have their shapes (`_checks.check_shapes`)."""
    holds = np.asarray(_holds(finger))
    if holds.all():
        return None
    k = int(np.argmin(holds))
    ok, values = jax.device_get(_verdict(finger, k))
    ok = np.asarray(ok)
    i = None if ok.ndim == 0 else int(np.argmin(ok))
    return RULES[k].message(types.SimpleNamespace(**values), i)
