"""The finger: material, beams, crossbeams, adaptor and loads, as equinox Modules.

Design values are float64 arrays (changing them never recompiles). What fixes shapes or
code paths (counts, boundary-condition kinds, the beam a load acts on) is static.
"""

import dataclasses
import os
import sys
import warnings

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from ._bases import AbstractBase, ClampedBase, as_base
from ._contact import Contact
from ._errors import FingerError, FingerWarning
from ._geometry import (
    AbstractTorsion,
    PaperTorsion,
    as_torsion,
    geometry,
    main_beam_arc,
    main_beam_samples,
    xz,
)
from ._objects import AbstractObject
from ._types import as_float

FRONT, BACK = 0, 1


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
# Eager validation: every rule names the field and the value.
# --------------------------------------------------------------------------------------


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def _warn(message: str) -> None:
    """warnings.warn(message, FingerWarning) attributed to the first caller outside
    finray_jax (the user's line that solved, validated or read the finger)."""
    level, frame = 1, sys._getframe(0)
    while frame.f_back is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, FingerWarning, stacklevel=level)


def _num(x):
    return np.asarray(x, dtype=np.float64)


def _finite(name, value):
    v = _num(value)
    if not np.all(np.isfinite(v)):
        raise FingerError(f"{name} must be finite, got {v.tolist()}")
    return v


def _shaped(name, value, shape):
    v = _num(value)
    if v.shape != shape:
        want = "a number" if shape == () else f"{shape[0]} numbers"
        raise FingerError(f"{name} must be {want}, got {v.tolist()}")
    return v


def _positive(name, value):
    v = _finite(name, value)
    if np.any(v <= 0):
        raise FingerError(f"{name} must be positive, got {v.tolist()}")
    return v


# The eager checks evaluate the geometry as one compiled call each: op by op it took
# ~150 dispatches and ~20 ms per solve_finger call (a finger's leaves are all arrays, so
# plain jax.jit takes it, with less dispatch than eqx.filter_jit).
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
    """Check a finger eagerly; raise FingerError naming the field and value."""
    cb = finger.crossbeams
    shapes = {k: np.shape(getattr(cb, k)) for k in ("front_s", "back_s", "thickness", "depth")}
    if len(set(shapes.values())) != 1 or len(shapes["front_s"]) != 1:
        raise FingerError(f"crossbeam arrays must be 1-D of equal length, got shapes {shapes}")
    geo = jax.device_get(_geometry(finger))
    lengths = geo.length.tolist()  # front, back, crossbeams
    finger = jax.device_get(finger)  # the checks below run on numpy values
    m = finger.material
    _positive("material.E", m.E)
    nu = _finite("material.nu", m.nu)
    if not (-1.0 < nu < 0.5):
        raise FingerError(f"material.nu must lie in (-1, 0.5), got {float(nu)}")
    _positive("material.shear_coefficient", m.shear_coefficient)
    for name in ("front_base", "back_base", "tip"):
        v = _finite(name, getattr(finger, name))
        if v.shape != (2,):
            raise FingerError(f"{name} must be a point (x, z), got {v.tolist()}")
    for name in ("E", "nu", "shear_coefficient"):
        _shaped(f"material.{name}", getattr(m, name), ())
    for beam in ("front", "back"):
        sec = getattr(finger, beam)
        _positive(f"{beam}.thickness", _shaped(f"{beam}.thickness", sec.thickness, ()))
        if sec.tip_thickness is not None:
            name = f"{beam}.tip_thickness"
            _positive(name, _shaped(name, sec.tip_thickness, ()))
        _positive(f"{beam}.depth", _shaped(f"{beam}.depth", sec.depth, ()))
    for name in ("front_curvature", "back_curvature"):
        kappa = float(_finite(name, _shaped(name, getattr(finger, name), ())))
        base = _num(finger.front_base if name.startswith("front") else finger.back_base)
        chord = float(np.linalg.norm(_num(finger.tip) - base))
        if abs(kappa) * chord / 2.0 >= 0.99:
            raise FingerError(
                f"{name} = {kappa} is too large for a chord of {chord:.6g} mm: "
                f"|curvature| * chord / 2 must stay below 0.99 (at most a near half circle)"
            )
    lf, lb = lengths[:2]
    if lf <= 0:
        raise FingerError(f"front beam has zero length: front_base equals tip {finger.tip}")
    if lb <= 0:
        raise FingerError(f"back beam has zero length: back_base equals tip {finger.tip}")
    if np.allclose(_num(finger.front_base), _num(finger.back_base)):
        raise FingerError("front_base and back_base coincide")
    front_line, back_line = _centrelines(finger, geo)
    _check_main_beams_apart(finger, front_line, back_line)

    cb = finger.crossbeams
    fs = _num(cb.front_s)
    bs = _num(cb.back_s)
    for name, check in (
        ("front_s", _finite),
        ("back_s", _finite),
        ("thickness", _positive),
        ("depth", _positive),
    ):
        v = _num(getattr(cb, name))
        bad = ~np.isfinite(v) | ((v <= 0) if check is _positive else False)
        if np.any(bad):  # name the first bad crossbeam
            i = int(np.argmax(bad))
            check(f"crossbeams[{i}].{name}", v[i])
    for i, (a, b) in enumerate(zip(fs, bs)):
        if not 0.0 < a < lf:
            raise FingerError(
                f"crossbeams[{i}].front_s = {a} lies outside the front beam (0, {lf:.6g})"
            )
        if not 0.0 < b < lb:
            raise FingerError(
                f"crossbeams[{i}].back_s = {b} lies outside the back beam (0, {lb:.6g})"
            )
    for i in range(len(fs) - 1):
        df, db = fs[i + 1] - fs[i], bs[i + 1] - bs[i]
        if df * db <= 0 or df == 0:
            raise FingerError(
                f"crossbeams {i} and {i + 1} cross or touch: front_s {fs[i]} -> {fs[i + 1]}, "
                f"back_s {bs[i]} -> {bs[i + 1]} (list crossbeams in increasing front_s, "
                "with back_s increasing too)"
            )
        if df < 0:
            raise FingerError(
                f"crossbeams must be listed base to tip: crossbeams[{i + 1}].front_s = "
                f"{fs[i + 1]} < crossbeams[{i}].front_s = {fs[i]}"
            )
    if len(fs):
        # half the sum of the main beams' half thicknesses at the two ends
        least = 0.5 * (front_line.half(fs) + back_line.half(bs))
        for i, length in enumerate(lengths[2:]):
            if length < least[i]:
                raise FingerError(
                    f"crossbeams[{i}] is {length:.4g} mm long (from front_s = {fs[i]} to "
                    f"back_s = {bs[i]}): a crossbeam must be at least {least[i]:.4g} mm long "
                    "(half the sum of the main beams' half thicknesses at its ends); "
                    "a shorter one joins nearly coincident points"
                )

    ad = finger.adaptor
    for name, kind, length, total in (
        ("front", ad.front_base, ad.front_clamp_length, lf),
        ("back", ad.back_base, ad.back_clamp_length, lb),
    ):
        lc = float(_finite(f"adaptor.{name}_clamp_length", length))
        if not 0.0 <= lc < total:
            raise FingerError(f"adaptor.{name}_clamp_length must lie in [0, {total:.6g}), got {lc}")
        curvature = float(_num(getattr(finger, f"{name}_curvature")))
        if lc > 0 and curvature != 0.0:
            raise FingerError(
                f"adaptor.{name}_clamp_length = {lc} with {name}_curvature = {curvature}: "
                "a clamp on a curved beam is not supported yet"
            )
        if lc > 0 and not kind.holds_clamp:
            raise FingerError(
                f"adaptor.{name}_clamp_length = {lc} needs adaptor.{name}_base = 'clamped', "
                f"got {kind.name!r}"
            )

    sl = ad.support_length
    if sl is not None:
        ls = float(_finite("adaptor.support_length", _shaped("adaptor.support_length", sl, ())))
        lc = float(_num(ad.back_clamp_length))
        if not lc <= ls <= lb:
            raise FingerError(
                f"adaptor.support_length = {ls} must lie in [back_clamp_length, back beam "
                f"length] = [{lc}, {lb:.6g}] (the support backs the back beam from the end "
                "of the clamp)"
            )
        if float(_num(finger.back_curvature)) != 0.0:
            raise FingerError(
                "adaptor.support_length needs a straight back beam "
                f"(back_curvature = {float(_num(finger.back_curvature))})"
            )
    _validate_contact(finger)

    for j, load in enumerate(finger.loads):
        where = f"loads[{j}]"
        if not isinstance(load.beam, int) or not 0 <= load.beam < finger.n_beams:
            raise FingerError(
                f"{where}.beam = {load.beam!r} names no beam (0 front, 1 back, "
                f"2..{finger.n_beams - 1} crossbeams)"
            )
        total = lengths[load.beam]
        if isinstance(load, PointLoad):
            s = float(_finite(f"{where}.s", _shaped(f"{where}.s", load.s, ())))
            _finite(f"{where}.force", _shaped(f"{where}.force", load.force, (3,)))
            _finite(f"{where}.moment", _shaped(f"{where}.moment", load.moment, (3,)))
            if not 0.0 < s <= total:
                raise FingerError(
                    f"{where}.s = {s} lies outside the {beam_name(load.beam)} beam (0, {total:.6g}]"
                )
            _warn_if_clamped(finger, j, load.beam, f"s = {s}", s, s)
        elif isinstance(load, DistributedLoad):
            s0, s1 = _finite(f"{where}.s_range", _shaped(f"{where}.s_range", load.s_range, (2,)))
            _finite(f"{where}.total_force", _shaped(f"{where}.total_force", load.total_force, (3,)))
            if not 0.0 <= s0 < s1 <= total:
                raise FingerError(
                    f"{where}.s_range = [{s0}, {s1}] must satisfy 0 <= s0 < s1 <= {total:.6g} "
                    f"on the {beam_name(load.beam)} beam"
                )
            s0, s1 = float(s0), float(s1)
            _warn_if_clamped(finger, j, load.beam, f"s_range = [{s0}, {s1}]", s0, s1)
        else:
            raise FingerError(f"{where} is not a PointLoad or DistributedLoad: {load!r}")


def _warn_if_clamped(finger: Finger, j: int, beam: int, where: str, s0: float, s1: float):
    """Warn when load j, on [s0, s1] of a main beam (s0 = s1 for a point load), lies in
    that beam's clamped length [0, l_c]: the rigid adaptor carries it."""
    if beam not in (FRONT, BACK):
        return
    name = beam_name(beam)
    lc = float(_num(getattr(finger.adaptor, f"{name}_clamp_length")))
    if lc <= 0.0 or s0 > lc or (s0 == lc and s1 > s0):
        return  # outside, or a distributed load that only starts at the clamp's end
    what = f"loads[{j}] (beam {name}, {where})"
    field = f"adaptor.{name}_clamp_length"
    if s1 <= lc:
        _warn(
            f"{what} lies inside the {name} beam's clamped length {lc} mm ({field}): "
            "the adaptor carries it, so it does not deform the finger"
        )
    else:
        _warn(
            f"{what} lies partly inside the {name} beam's clamped length {lc} mm ({field}): "
            f"the adaptor carries its part on [{s0}, {lc}]"
        )


@dataclasses.dataclass(frozen=True)
class _Centreline:
    """A main beam's undeformed centreline for the eager geometry checks (numpy): points
    along it, and the polyline other points are measured against (its two ends when the
    beam is straight, the points themselves when it is an arc)."""

    s: np.ndarray  # (n,) arc lengths, 0 to the beam's length
    p: np.ndarray  # (n, 2) points (x, z)
    path_s: np.ndarray  # (m,) the polyline's arc lengths
    path_p: np.ndarray  # (m, 2) its points
    t0: float  # thickness at the base
    t1: float  # thickness at the tip
    length: float
    tangent_at_tip: np.ndarray  # (2,) unit tangent (x, z), base to tip

    def half(self, s):
        """Half thickness at arc lengths s."""
        return 0.5 * (self.t0 + (self.t1 - self.t0) * np.asarray(s) / self.length)


CENTRELINE_SAMPLES = 101  # points a main beam's centreline is sampled at (its checks)


def _centrelines(
    finger: Finger, geo, n: int = CENTRELINE_SAMPLES
) -> tuple[_Centreline, _Centreline]:
    """The front and back beams' undeformed centrelines at n points each, computed as in
    `_geometry.arc_point` (a circular arc of constant precurvature, or a straight line)."""
    out = []
    for b, sec in ((FRONT, finger.front), (BACK, finger.back)):
        base = np.asarray(geo.base[b], dtype=np.float64)[[0, 2]]
        theta, kappa = float(geo.theta[b]), float(geo.curvature[b])
        length = float(geo.length[b])
        s = np.linspace(0.0, length, n)
        half = theta + 0.5 * kappa * s
        r = s * np.sinc(0.5 * kappa * s / np.pi)  # np.sinc(x) = sin(pi x) / (pi x)
        p = base + r[:, None] * np.stack([np.sin(half), np.cos(half)], axis=-1)
        p[-1] = _num(finger.tip)  # the shared tip exactly
        ends = [0, n - 1] if kappa == 0.0 else slice(None)
        t0 = float(_num(sec.thickness))
        t1 = t0 if sec.tip_thickness is None else float(_num(sec.tip_thickness))
        end = theta + kappa * length
        tangent = np.array([np.sin(end), np.cos(end)])
        out.append(_Centreline(s, p, s[ends], p[ends], t0, t1, length, tangent))
    return out[0], out[1]


def _nearest(line: _Centreline, points):
    """Distance from each point (k, 2) to a centreline's polyline, and the arc length of
    the nearest point on it."""
    ax, az = line.path_p[:-1, 0], line.path_p[:-1, 1]
    ex, ez = np.diff(line.path_p[:, 0]), np.diff(line.path_p[:, 1])
    rx, rz = points[:, :1] - ax, points[:, 1:] - az  # (k, m - 1)
    t = np.clip((rx * ex + rz * ez) / (ex * ex + ez * ez), 0.0, 1.0)
    dist = np.hypot(rx - t * ex, rz - t * ez)
    j = np.argmin(dist, axis=1)
    k = np.arange(len(points))
    return dist[k, j], line.path_s[j] + t[k, j] * np.diff(line.path_s)[j]


def _crossing(front: _Centreline, back: _Centreline):
    """(back s, front s, point) of the first crossing of the two centrelines' polylines
    before the tip they share, or None."""
    P, Q = back.path_p, front.path_p
    ax, az = P[:-1, 0, None], P[:-1, 1, None]  # back segments (i), down
    bx, bz = np.diff(P[:, 0])[:, None], np.diff(P[:, 1])[:, None]
    cx, cz = Q[None, :-1, 0], Q[None, :-1, 1]  # front segments (j), across
    dx, dz = np.diff(Q[:, 0])[None], np.diff(Q[:, 1])[None]
    d1 = bx * (cz - az) - bz * (cx - ax)  # sides of the front segment's ends
    d2 = bx * (cz + dz - az) - bz * (cx + dx - ax)
    d3 = dx * (az - cz) - dz * (ax - cx)  # sides of the back segment's ends
    d4 = dx * (az + bz - cz) - dz * (ax + bx - cx)
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    hit[-1, -1] = False  # the last segments meet at the tip
    if not np.any(hit):
        return None
    i, j = np.argwhere(hit)[0]
    ta = d3[i, j] / (d3[i, j] - d4[i, j])
    tc = d1[i, j] / (d1[i, j] - d2[i, j])
    sb = back.path_s[i] + ta * (back.path_s[i + 1] - back.path_s[i])
    sf = front.path_s[j] + tc * (front.path_s[j + 1] - front.path_s[j])
    return float(sb), float(sf), P[i] + ta * (P[i + 1] - P[i])


def _fmt(p) -> str:
    """A point (x, z) to 4 digits (round-off below 1e-9 mm shown as 0)."""
    return "(" + ", ".join(f"{round(float(x), 9) + 0.0:.4g}" for x in p) + ")"


def _check_main_beams_apart(finger: Finger, front: _Centreline, back: _Centreline) -> None:
    """The front and back beams' undeformed centrelines stay apart by at least the sum of
    their half thicknesses, except near the tip they share; they never cross."""
    fields = (
        f"front_base = {_num(finger.front_base).tolist()}, back_base = "
        f"{_num(finger.back_base).tolist()}, tip = {_num(finger.tip).tolist()}"
    )
    for name in ("front_curvature", "back_curvature"):
        kappa = float(_num(getattr(finger, name)))
        if kappa != 0.0:
            fields += f", {name} = {kappa}"
    tol = 1e-9 * max(front.length, back.length)
    # Each base against the other beam (the rule for the back base is the one that matters
    # in practice; the front base's is its mirror image).
    for base_name, own, other in (("back_base", back, front), ("front_base", front, back)):
        d, s = _nearest(other, own.p[:1])
        least = own.half(0.0) + float(other.half(s[0]))
        if d[0] < least:
            where = "on" if d[0] <= tol else f"{d[0]:.4g} mm from"
            own_name, other_name = ("back", "front") if other is front else ("front", "back")
            raise FingerError(
                f"{base_name} = {own.p[0].tolist()} lies {where} the {other_name} beam's "
                f"centreline (nearest at {other_name} s = {s[0]:.4g}): it must lie at least "
                f"{least:.4g} mm from it (half of {own_name}.thickness = "
                f"{2 * own.half(0.0):.4g} mm at the base plus half of {other_name}.thickness "
                f"= {2 * float(other.half(s[0])):.4g} mm there), or the two beams overlap; "
                "they may meet only at the tip"
            )
    hit = _crossing(front, back)
    if hit is not None:
        sb, sf, p = hit
        raise FingerError(
            f"the back beam crosses the front beam at (x, z) = {_fmt(p)} (back s = {sb:.4g}, "
            f"front s = {sf:.4g}): the two beams may meet only at the tip ({fields})"
        )
    # Near the tip the beams necessarily come together: within r of it, the centrelines of
    # two beams meeting at an angle alpha lie about r sin(alpha) apart. Exempt twice the
    # distance over which that is less than the two half thicknesses at the tip (alpha
    # capped at 90 degrees), but never more than a quarter of the shorter beam's length.
    cos_alpha = float(np.clip(front.tangent_at_tip @ back.tangent_at_tip, -1.0, 1.0))
    sin_alpha = 1.0 if cos_alpha <= 0.0 else float(np.sqrt(1.0 - cos_alpha**2))
    at_tip = float(front.half(front.length) + back.half(back.length))
    zone = 0.25 * min(front.length, back.length)
    if 2.0 * at_tip < zone * sin_alpha:
        zone = 2.0 * at_tip / sin_alpha
    tip = _num(finger.tip)
    worst = None  # (shortfall ratio, distance, least, front s, back s, point)
    for own, other in ((back, front), (front, back)):
        keep = np.linalg.norm(own.p - tip, axis=-1) >= zone
        if not np.any(keep):
            continue
        d, s_other = _nearest(other, own.p[keep])
        least = own.half(own.s[keep]) + other.half(s_other)
        ratio = d / least
        k = int(np.argmin(ratio))
        if ratio[k] < 1.0 and (worst is None or ratio[k] < worst[0]):
            s_own = float(own.s[keep][k])
            sf, sb = (s_own, float(s_other[k])) if own is front else (float(s_other[k]), s_own)
            worst = (ratio[k], float(d[k]), float(least[k]), sf, sb, own.p[keep][k])
    if worst is not None:
        _, d, least, sf, sb, p = worst
        raise FingerError(
            f"the front and back beams' centrelines come within {d:.4g} mm of each other "
            f"at front s = {sf:.4g}, back s = {sb:.4g} (near (x, z) = {_fmt(p)}, "
            f"{float(np.linalg.norm(p - tip)):.4g} mm from the tip): apart from the last "
            f"{zone:.4g} mm before the tip they must stay at least {least:.4g} mm apart "
            f"(half the front plus half the back thickness there), or the beams overlap "
            f"({fields})"
        )


def out_of_plane_load(finger: Finger) -> str | None:
    """The first load with a part out of the x-z plane (a y force, an x or z moment), as
    'loads[i].field = value', or None when every load acts in the plane."""
    for i, load in enumerate(finger.loads):
        if isinstance(load, PointLoad):
            moment = _num(load.moment)
            if abs(float(load.force[1])) > 0:
                return f"loads[{i}].force = {_num(load.force).tolist()}"
            if np.any(np.abs(moment[[0, 2]]) > 0):
                return f"loads[{i}].moment = {moment.tolist()}"
        elif abs(float(load.total_force[1])) > 0:
            return f"loads[{i}].total_force = {_num(load.total_force).tolist()}"
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
        if any(np.any(_num(v) != 0.0) for v in parts):
            return False
    return True


def _validate_contact(finger: Finger) -> None:
    c = finger.contact
    if c.stiffness is not None:
        _positive("contact.stiffness", _shaped("contact.stiffness", c.stiffness, ()))
    mp = float(_finite("contact.max_penetration", c.max_penetration))
    if not 0.0 < mp < 0.5:
        raise FingerError(
            f"contact.max_penetration must lie in (0, 0.5) (a fraction of the "
            f"front beam's thickness), got {mp}"
        )
    if c.support_stiffness is not None:
        _positive(
            "contact.support_stiffness",
            _shaped("contact.support_stiffness", c.support_stiffness, ()),
        )
    if c.max_support_penetration is not None:
        ms = float(_finite("contact.max_support_penetration", c.max_support_penetration))
        if not 0.0 < ms < 0.5:
            raise FingerError(
                f"contact.max_support_penetration must lie in (0, 0.5) (a fraction of the "
                f"back beam's thickness), got {ms}"
            )
    mu = float(_finite("contact.friction", c.friction))
    if mu < 0:
        raise FingerError(f"contact.friction must be non-negative, got {mu}")
    _positive("contact.friction_regularisation", c.friction_regularisation)
    _shaped("contact.slip_direction", _finite("contact.slip_direction", c.slip_direction), (2,))
    if not (isinstance(c.segment_length, (int, float)) and c.segment_length > 0):
        raise FingerError(f"contact.segment_length must be positive, got {c.segment_length!r}")
    near = c.near_segments
    if near is not None and not (isinstance(near, int) and not isinstance(near, bool) and near > 0):
        raise FingerError(
            "contact.near_segments must be a positive integer or None (every segment), "
            f"got {near!r}"
        )
    for i, obj in enumerate(finger.objects):
        _validate_object(f"objects[{i}]", obj)
    for i, obj in enumerate(finger.objects):
        hit = _overlap(finger, obj)
        if hit is not None:
            beam, s, depth = hit
            raise FingerError(
                f"objects[{i}] ({obj.kind}) overlaps the {beam} beam at the start, at s = "
                f"{s:.4g} mm by {depth:.4g} mm: place objects clear of the finger (the grasp "
                "closes the finger onto them)"
            )


def _validate_object(where: str, obj) -> None:
    if not isinstance(obj, AbstractObject):
        raise FingerError(f"{where} is not an object (Circle, Ellipse, ...): {obj!r}")
    for name in ("center", "point", "normal"):
        if hasattr(obj, name):
            _shaped(f"{where}.{name}", _finite(f"{where}.{name}", getattr(obj, name)), (2,))
    kind = obj.kind
    if kind == "circle":
        _positive(f"{where}.radius", _shaped(f"{where}.radius", obj.radius, ()))
    elif kind == "ellipse":
        _positive(f"{where}.semi_axes", _shaped(f"{where}.semi_axes", obj.semi_axes, (2,)))
        _finite(f"{where}.angle", obj.angle)
    elif kind == "rounded_rectangle":
        half = _positive(f"{where}.half_size", _shaped(f"{where}.half_size", obj.half_size, (2,)))
        r = float(_finite(f"{where}.corner_radius", obj.corner_radius))
        if not 0.0 <= r <= float(np.min(half)):
            raise FingerError(
                f"{where}.corner_radius must lie in [0, {float(np.min(half))}] "
                f"(the smaller half size), got {r}"
            )
        _finite(f"{where}.angle", obj.angle)
    elif kind == "polygon":
        v = _finite(f"{where}.vertices", obj.vertices)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
            raise FingerError(f"{where}.vertices must be 3 or more (x, z) points, got {v.tolist()}")
        e = np.roll(v, -1, axis=0) - v
        turn = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
        if np.any(turn <= 0):
            raise FingerError(
                f"{where}.vertices must form a convex polygon listed counter-"
                f"clockwise (x right, z up), got {v.tolist()}"
            )
        r = float(_finite(f"{where}.corner_radius", obj.corner_radius))
        if r < 0:
            raise FingerError(f"{where}.corner_radius must be non-negative, got {r}")
    elif kind == "half_plane":
        if np.linalg.norm(_num(obj.normal)) == 0:
            raise FingerError(f"{where}.normal must be non-zero, got {_num(obj.normal).tolist()}")


def _overlap(finger: Finger, obj, samples: int = 401):
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
