"""Undeformed geometry of a finger and the stiffness of its sections.

Main beams run from their base to the shared tip, straight or as circular arcs of constant
precurvature; crossbeams are straight between their attachment points. Everything here is
plain jax.numpy: it runs traced inside the solver and eagerly in the validation.
"""

import abc
import functools
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ._choices import choice


class Geometry(eqx.Module):
    """Undeformed geometry of every beam: base point (3-D), start angle, arc length and
    precurvature (main beams may be circular arcs; crossbeams are straight)."""

    base: jax.Array  # (B, 3)
    theta: jax.Array  # (B,) tangent angle at s = 0
    length: jax.Array  # (B,) arc length
    curvature: jax.Array  # (B,) constant in-plane precurvature (0 for crossbeams)
    L: jax.Array  # length scale (front-beam length)
    F: jax.Array  # force scale (front-beam EI / L^2)


def xz(p2):
    """3-D points (x, 0, z) from (x, z) pairs."""
    return jnp.stack([p2[..., 0], jnp.zeros_like(p2[..., 0]), p2[..., 1]], axis=-1)


def _sinc(x):
    """sin(x)/x, smooth through 0."""
    small = jnp.abs(x) < 1e-4
    xs = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0 - x * x / 6.0, jnp.sin(xs) / xs)


def _asinc(x):
    """asin(x)/x, smooth through 0."""
    small = jnp.abs(x) < 1e-4
    xs = jnp.where(small, 0.5, x)
    return jnp.where(small, 1.0 + x * x / 6.0, jnp.arcsin(xs) / xs)


def main_beam_arc(base, tip, curvature):
    """A main beam from base to tip (3-vectors) with constant in-plane precurvature (1/mm;
    positive turns the tangent from +z toward +x): (arc length, start angle theta0)."""
    chord = tip - base
    c = jnp.linalg.norm(chord)
    length = c * _asinc(0.5 * curvature * c)
    theta_c = jnp.arctan2(chord[0], chord[2])
    return length, theta_c - 0.5 * curvature * length


def arc_point(base, theta0, curvature, s):
    """Undeformed centreline point at arc length s (s may be an array)."""
    s = jnp.asarray(s)
    half = theta0 + 0.5 * curvature * s
    r = s * _sinc(0.5 * curvature * s)
    return base + jnp.stack([r * jnp.sin(half), jnp.zeros_like(r), r * jnp.cos(half)], axis=-1)


def geometry(finger) -> Geometry:
    """Geometry of every beam (front, back, crossbeams) of a Finger."""
    fb, bb, tip = xz(finger.front_base), xz(finger.back_base), xz(finger.tip)
    kf, kb = finger.front_curvature, finger.back_curvature
    lf, th_f = main_beam_arc(fb, tip, kf)
    lb, th_b = main_beam_arc(bb, tip, kb)
    cb = finger.crossbeams
    pf = arc_point(fb, th_f, kf, cb.front_s)
    pb = arc_point(bb, th_b, kb, cb.back_s)
    d = pb - pf
    lc = jnp.linalg.norm(d, axis=-1)
    base = jnp.concatenate([jnp.stack([fb, bb]), pf], axis=0)
    theta = jnp.concatenate([jnp.stack([th_f, th_b]), jnp.arctan2(d[:, 0], d[:, 2])])
    length = jnp.concatenate([jnp.stack([lf, lb]), lc])
    curvature = jnp.concatenate([jnp.stack([kf, kb]), jnp.zeros_like(lc)])
    m = finger.material
    ei_front = m.E * finger.front.depth * finger.front.thickness**3 / 12.0
    return Geometry(base, theta, length, curvature, lf, ei_front / lf**2)


def thickness_at(section, s, length):
    """A main beam's thickness at arc length s: linear from its base to its tip
    (`tip_thickness`, None: constant) over the beam's length."""
    tip = section.thickness if section.tip_thickness is None else section.tip_thickness
    return section.thickness + (tip - section.thickness) * s / length


@functools.partial(jax.jit, static_argnums=1)
def main_beam_samples(finger, n: int):
    """The undeformed main beams at n evenly spaced arc lengths each, for eager checks:
    arc lengths (2, n), centreline points (x, z) (2, n, 2) and half thicknesses (2, n),
    front beam first. (Jitted: run eagerly, its few dozen small operations would each be
    dispatched on their own.)"""
    geo = geometry(finger)
    out = []
    for b, sec in ((0, finger.front), (1, finger.back)):
        s = jnp.linspace(0.0, 1.0, n) * geo.length[b]
        p = arc_point(geo.base[b], geo.theta[b], geo.curvature[b], s)[:, ::2]
        out.append((s, p, 0.5 * thickness_at(sec, s, geo.length[b])))
    return tuple(jnp.stack(x) for x in zip(*out))


class AbstractTorsion(eqx.Module):
    """How a rectangular section's torsion constant J is taken; `name` is its word in
    finger files."""

    name: ClassVar[str]

    @abc.abstractmethod
    def constant(self, thickness, depth):
        """J (mm^4) of a thickness x depth rectangle."""


class PaperTorsion(AbstractTorsion):
    """J = Ixx + Iyy, the polar moment, as the paper's model takes it (the default)."""

    name: ClassVar[str] = "paper"

    def constant(self, thickness, depth):
        return thickness * depth * (thickness**2 + depth**2) / 12.0


class SaintVenantTorsion(AbstractTorsion):
    """Saint-Venant's torsion constant of a solid rectangle (Roark's series to b^4/a^4)."""

    name: ClassVar[str] = "rectangle"

    def constant(self, thickness, depth):
        a = jnp.maximum(thickness, depth)
        b = jnp.minimum(thickness, depth)
        return a * b**3 * (1.0 / 3.0 - 0.21 * (b / a) * (1.0 - b**4 / (12.0 * a**4)))


TORSIONS = {kind.name: kind() for kind in (PaperTorsion, SaintVenantTorsion)}


def as_torsion(value, field: str = "torsion") -> AbstractTorsion:
    """A finger's `torsion` as its object (a name is deprecated, see `choice`)."""
    return choice(value, field, AbstractTorsion, TORSIONS)


def section_stiffness(material, thickness, depth, torsion: AbstractTorsion):
    """(..., 6) kGA1, kGA2, EA, EI1, EI2, GJ of a rectangle (thickness in plane)."""
    E, G, k = material.E, material.G, material.shear_coefficient
    A = thickness * depth
    I1 = thickness * depth**3 / 12.0  # about d1: out of plane
    I2 = depth * thickness**3 / 12.0  # about d2: in plane
    J = torsion.constant(thickness, depth)
    return jnp.stack([k * G * A, k * G * A, E * A, E * I1, E * I2, G * J], axis=-1)
