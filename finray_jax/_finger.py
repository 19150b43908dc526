"""The finger: material, beams, crossbeams, adaptor and loads, as equinox Modules.

Design values are float64 arrays (changing them never recompiles). What fixes shapes or
code paths (counts, boundary-condition kinds, the beam a load acts on) is static.
"""

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from ._bases import AbstractBase, ClampedBase, as_base
from ._centrelines import BACK, FRONT
from ._checks import check_contact, check_finite, check_shapes, numbers, shaped, warn
from ._contact import Contact
from ._errors import FingerError
from ._geometry import (
    AbstractTorsion,
    PaperTorsion,
    as_torsion,
    geometry,
    main_beam_arc,
    xz,
)
from ._objects import AbstractObject
from ._rules import broken_rule
from ._types import as_float


class Material(eqx.Module):
    """Linear elastic material. E in MPa; shear_coefficient is Timoshenko's k (5/6 for a
    rectangle; the paper's Eq. 2 uses 1)."""

    E: Float[Array, ""] = eqx.field(converter=as_float)
    nu: Float[Array, ""] = eqx.field(converter=as_float)
    shear_coefficient: Float[Array, ""] = eqx.field(converter=as_float, default=5.0 / 6.0)

    @property
    def G(self):
        return self.E / (2.0 * (1.0 + self.nu))


def _optional_float(x):
    return None if x is None else as_float(x)


class Section(eqx.Module):
    """Rectangular cross-section: thickness in the finger plane, depth out of plane (mm).

    tip_thickness: for a main beam, the thickness at its tip; the thickness then varies
    linearly from `thickness` at the base (None: constant). Setting it (or not) is part of
    the topology: it selects the varying-section rod parameters.
    """

    thickness: Float[Array, ""] = eqx.field(converter=as_float)
    depth: Float[Array, ""] = eqx.field(converter=as_float)
    tip_thickness: Float[Array, ""] | None = eqx.field(converter=_optional_float, default=None)


class Crossbeams(eqx.Module):
    """All crossbeams, as arrays of equal length (one entry per crossbeam).

    front_s, back_s: attachment arc lengths on the front and back beams (mm).
    """

    front_s: Float[Array, " c"] = eqx.field(converter=as_float)
    back_s: Float[Array, " c"] = eqx.field(converter=as_float)
    thickness: Float[Array, " c"] = eqx.field(converter=as_float)
    depth: Float[Array, " c"] = eqx.field(converter=as_float)

    @property
    def count(self) -> int:
        return int(np.shape(self.front_s)[0])


class Adaptor(eqx.Module):
    """How the mounting adaptor holds the two main beams.

    front_base, back_base: ClampedBase(), PinnedBase() or FreeBase() (static).
    front_clamp_length, back_clamp_length: length from the base held rigidly by the
        adaptor (mm, continuous design values; needs a clamped base when positive).
        Crossbeams landing inside a clamped length attach to the rigid adaptor.
    support_length: l_s (mm) or None. The modified adaptor's rigid support behind the
        back beam over [back_clamp_length, l_s]: it stops the back beam moving backward
        but lets it move forward (unilateral penalty contact, see `Contact`). Whether
        there is a support is static; its length is a design value.
    """

    front_base: AbstractBase = eqx.field(
        static=True, default=ClampedBase(), converter=lambda v: as_base(v, "adaptor.front_base")
    )
    back_base: AbstractBase = eqx.field(
        static=True, default=ClampedBase(), converter=lambda v: as_base(v, "adaptor.back_base")
    )
    front_clamp_length: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)
    back_clamp_length: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)
    support_length: Float[Array, ""] | None = eqx.field(converter=_optional_float, default=None)


class AbstractLoad(eqx.Module):
    """A load on one beam: beam 0 is the front beam, 1 the back beam, 2 + i crossbeam i."""

    beam: eqx.AbstractVar[int]


class PointLoad(AbstractLoad):
    """Dead point force (N) and moment (N mm), world frame, at arc length s of a beam."""

    beam: int = eqx.field(static=True)
    s: Float[Array, ""] = eqx.field(converter=as_float)
    force: Float[Array, "3"] = eqx.field(converter=as_float)
    moment: Float[Array, "3"] = eqx.field(converter=as_float, default=(0.0, 0.0, 0.0))


class DistributedLoad(AbstractLoad):
    """Dead force spread uniformly over arc lengths s_range = (s0, s1) of a beam;
    total_force (N, world frame) is the resultant."""

    beam: int = eqx.field(static=True)
    s_range: Float[Array, "2"] = eqx.field(converter=as_float)
    total_force: Float[Array, "3"] = eqx.field(converter=as_float)

    @property
    def force_per_length(self):
        return self.total_force / (self.s_range[1] - self.s_range[0])


class Finger(eqx.Module):
    """A fin-ray finger: two main beams joined at the tip, linked by crossbeams.

    Points are (x, z) in mm. The front beam runs from front_base to tip, the back beam
    from back_base to tip. front_curvature, back_curvature (1/mm, default 0: straight)
    make a main beam an undeformed circular arc from base to tip with that precurvature;
    positive turns its tangent from +z toward +x. Arc lengths (attachments, loads) are
    measured along the arc.
    torsion: how GJ is taken: PaperTorsion() (G (Ixx + Iyy), default) or
        SaintVenantTorsion().
    objects: rigid objects (Circle, Ellipse, ...) the beams may touch; contact: how.
    """

    material: Material
    front_base: Float[Array, "2"] = eqx.field(converter=as_float)
    back_base: Float[Array, "2"] = eqx.field(converter=as_float)
    tip: Float[Array, "2"] = eqx.field(converter=as_float)
    front: Section
    back: Section
    crossbeams: Crossbeams
    adaptor: Adaptor = Adaptor()
    loads: tuple[AbstractLoad, ...] = ()
    front_curvature: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)
    back_curvature: Float[Array, ""] = eqx.field(converter=as_float, default=0.0)
    torsion: AbstractTorsion = eqx.field(static=True, default=PaperTorsion(), converter=as_torsion)
    objects: tuple[AbstractObject, ...] = ()
    contact: Contact = Contact()

    @property
    def n_crossbeams(self) -> int:
        return self.crossbeams.count

    @property
    def n_beams(self) -> int:
        return 2 + self.n_crossbeams

    def with_loads(self, *loads: AbstractLoad) -> "Finger":
        return eqx.tree_at(lambda f: f.loads, self, tuple(loads))

    def scale_loads(self, factor) -> "Finger":
        """The same finger with every load multiplied by `factor`."""

        def scaled(load):
            if isinstance(load, PointLoad):
                return PointLoad(load.beam, load.s, load.force * factor, load.moment * factor)
            return DistributedLoad(load.beam, load.s_range, load.total_force * factor)

        return eqx.tree_at(lambda f: f.loads, self, tuple(scaled(ld) for ld in self.loads))


def beam_name(beam: int) -> str:
    return {FRONT: "front", BACK: "back"}.get(beam, f"crossbeam {beam - 2}")


# --------------------------------------------------------------------------------------
# Eager validation: every check names the field and the value.
# --------------------------------------------------------------------------------------


# Beam lengths for the loads' checks, as one compiled call (a finger's leaves are all
# arrays, so plain jax.jit takes it, with less dispatch than eqx.filter_jit).
_geometry = jax.jit(geometry)


@eqx.filter_jit
def _main_lengths(tip, bases_and_curvatures):
    tip = xz(as_float(tip))
    return [
        main_beam_arc(xz(as_float(base)), tip, as_float(kappa))[0]
        for base, kappa in bases_and_curvatures
    ]


def beam_lengths(finger: Finger) -> tuple[float, float]:
    """Arc lengths of the front and back beams (needs only the main beams' fields)."""
    pairs = (
        (finger.front_base, finger.front_curvature),
        (finger.back_base, finger.back_curvature),
    )
    return tuple(float(x) for x in _main_lengths(finger.tip, pairs))


def validate_finger(finger: Finger) -> None:
    """Check a finger eagerly; raise FingerError naming the field and value.

    First what is not a design value: the shapes of the fields, the loads' kinds and
    beams, every number finite. Then the validity rules of the design (`_rules.RULES`,
    the same rules `design.design_valid` applies traced): the first one broken is
    reported. Then the contact model and objects, and the loads' positions (a load inside
    a clamped length warns)."""
    check_shapes(finger)
    _check_load_fields(finger)
    check_finite(finger)
    broken = broken_rule(finger)
    if broken is not None:
        raise FingerError(broken)
    check_contact(finger)
    _check_load_positions(finger)


def _check_load_fields(finger: Finger) -> None:
    """Each load a PointLoad or DistributedLoad on a beam of the finger, with values of
    the right shapes."""
    for j, load in enumerate(finger.loads):
        where = f"loads[{j}]"
        if not isinstance(load, (PointLoad, DistributedLoad)):
            raise FingerError(f"{where} is not a PointLoad or DistributedLoad: {load!r}")
        if not isinstance(load.beam, int) or not 0 <= load.beam < finger.n_beams:
            raise FingerError(
                f"{where}.beam = {load.beam!r} names no beam (0 front, 1 back, "
                f"2..{finger.n_beams - 1} crossbeams)"
            )
        if isinstance(load, PointLoad):
            fields = (("s", load.s, ()), ("force", load.force, (3,)))
            fields += (("moment", load.moment, (3,)),)
        else:
            fields = (("s_range", load.s_range, (2,)), ("total_force", load.total_force, (3,)))
        for name, value, shape in fields:
            shaped(f"{where}.{name}", value, shape)


def _check_load_positions(finger: Finger) -> None:
    """Each load on its beam (a point load on (0, length], a distributed load on
    0 <= s0 < s1 <= length); warn for a load inside a clamped length."""
    lengths = jax.device_get(_geometry(finger).length).tolist()  # front, back, crossbeams
    for j, load in enumerate(finger.loads):
        where, total = f"loads[{j}]", lengths[load.beam]
        if isinstance(load, PointLoad):
            s = float(numbers(load.s))
            if not 0.0 < s <= total:
                raise FingerError(
                    f"{where}.s = {s} lies outside the {beam_name(load.beam)} beam (0, {total:.6g}]"
                )
            _warn_if_clamped(finger, j, load.beam, f"s = {s}", s, s)
        else:
            s0, s1 = numbers(load.s_range)
            if not 0.0 <= s0 < s1 <= total:
                raise FingerError(
                    f"{where}.s_range = [{s0}, {s1}] must satisfy 0 <= s0 < s1 <= {total:.6g} "
                    f"on the {beam_name(load.beam)} beam"
                )
            s0, s1 = float(s0), float(s1)
            _warn_if_clamped(finger, j, load.beam, f"s_range = [{s0}, {s1}]", s0, s1)


def _warn_if_clamped(finger: Finger, j: int, beam: int, where: str, s0: float, s1: float):
    """Warn when load j, on [s0, s1] of a main beam (s0 = s1 for a point load), lies in
    that beam's clamped length [0, l_c]: the rigid adaptor carries it."""
    if beam not in (FRONT, BACK):
        return
    name = beam_name(beam)
    lc = float(numbers(getattr(finger.adaptor, f"{name}_clamp_length")))
    if lc <= 0.0 or s0 > lc or (s0 == lc and s1 > s0):
        return  # outside, or a distributed load that only starts at the clamp's end
    what = f"loads[{j}] (beam {name}, {where})"
    field = f"adaptor.{name}_clamp_length"
    if s1 <= lc:
        warn(
            f"{what} lies inside the {name} beam's clamped length {lc} mm ({field}): "
            "the adaptor carries it, so it does not deform the finger"
        )
    else:
        warn(
            f"{what} lies partly inside the {name} beam's clamped length {lc} mm ({field}): "
            f"the adaptor carries its part on [{s0}, {lc}]"
        )


def out_of_plane_load(finger: Finger) -> str | None:
    """The first load with a part out of the x-z plane (a y force, an x or z moment), as
    'loads[i].field = value', or None when every load acts in the plane."""
    for i, load in enumerate(finger.loads):
        if isinstance(load, PointLoad):
            moment = numbers(load.moment)
            if abs(float(load.force[1])) > 0:
                return f"loads[{i}].force = {numbers(load.force).tolist()}"
            if np.any(np.abs(moment[[0, 2]]) > 0):
                return f"loads[{i}].moment = {moment.tolist()}"
        elif abs(float(load.total_force[1])) > 0:
            return f"loads[{i}].total_force = {numbers(load.total_force).tolist()}"
    return None


def loads_in_plane(finger: Finger) -> bool:
    """True when every load acts in the x-z plane (no y force, no x or z moment)."""
    return out_of_plane_load(finger) is None


def check_mode_carries_loads(finger: Finger, mode: str) -> None:
    """Raise FingerError when `mode` is "planar" and a load acts out of the plane (planar
    mode would drop that part of it)."""
    off = out_of_plane_load(finger) if mode == "planar" else None
    if off is not None:
        raise FingerError(
            f"{off}: acts out of the x-z plane, which mode 'planar' cannot carry (it would be "
            "dropped); use mode 'spatial' or 'auto'"
        )


def loads_are_zero(finger: Finger) -> bool:
    """True when no load has a non-zero force or moment (or there are no loads)."""
    for load in finger.loads:
        parts = (load.force, load.moment) if isinstance(load, PointLoad) else (load.total_force,)
        if any(np.any(numbers(v) != 0.0) for v in parts):
            return False
    return True
