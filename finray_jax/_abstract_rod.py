"""The interface of a static Cosserat rod model, and the stiffness interpolation every
model shares.

A *segment* is a piece of one beam between two junctions or load points. Its start state
is an unknown of the shooting problem; its flow (`_flow`) maps that start state to the end
state. Every segment carries a parameter row q (length, rigid length, stiffnesses,
distributed force, precurvature). The first `rigid` millimetres of a segment are held
rigid (inside an adaptor clamp) and are transported in closed form; the rest is
integrated at fixed steps with a Runge-Kutta solver.
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._contact import ContactSpec, contact_load

# Sample points (in the flexible part of a segment, tau in [0, 1]) of a varying section.
TAPER_NODES = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])


def _lagrange_weights(tau):
    """Cubic Lagrange weights at TAPER_NODES: exact for stiffnesses cubic in tau."""
    x = TAPER_NODES
    w = []
    for i in range(4):
        wi = 1.0
        for j in range(4):
            if j != i:
                wi = wi * (tau - x[j]) / (x[i] - x[j])
        w.append(wi)
    return jnp.stack(w)


class AbstractRodModel(eqx.Module):
    """Interface of a rod model (a family of interchangeable implementations).

    tapered: the section varies along s; each segment then carries its stiffnesses at the
    four TAPER_NODES and the rhs interpolates them (static: it fixes the parameter size).
    """

    tapered: bool = eqx.field(static=True, default=False)
    contact: ContactSpec | None = eqx.field(static=True, default=None)
    name: ClassVar[str]
    n_unknown: ClassVar[int]  # unknowns per segment start state
    n_full: ClassVar[int]  # integrated state size
    n_stiff: ClassVar[int]  # stiffness entries per sample
    n_head: ClassVar[int]  # parameters before the stiffness samples
    rotation_slice: ClassVar[slice]  # the rotation part of a segment's unknowns
    position_slice: ClassVar[slice]  # the position part of a full state

    def split(self, q):
        """(stiffness samples, contact columns) of a parameter row."""
        k = self.n_stiff * (4 if self.tapered else 1)
        return q[self.n_head : self.n_head + k], q[self.n_head + k :]

    @property
    def has_contact_law(self) -> bool:
        """Whether the rhs evaluates a contact law: a contact layout that is not the
        law-free one of the far segments (`ContactSpec.free`)."""
        return self.contact is not None and not self.contact.empty

    def contact_at(self, q, x, z, tx, tz, tau):
        """Contact force (fx, fz) and moment l_y per length at centreline point (x, z)
        with unit tangent (tx, tz); plain zeros without contact (no ops traced)."""
        if not self.has_contact_law:
            return 0.0, 0.0, 0.0
        return contact_load(self.contact, self.split(q)[1], x, z, tx, tz, tau)

    @staticmethod
    def after_step(y0, y1):
        """The state after a Runge-Kutta step from y0 to y1 (a model may re-project it)."""
        return y1

    # --- directions of a start state that the segment flow must be differentiated in ---
    @property
    def translation_free(self) -> bool:
        """Without contact the flow commutes with translations: d(end)/d(start position)
        is the identity on the position and zero elsewhere, so it needs no integration."""
        return not self.has_contact_law

    def tangent_basis(self, y):
        """(n_full, k) directions spanning every tangent of the start state y (position
        directions left out when translation_free)."""
        raise NotImplementedError

    def tangent_coords(self, y, dy):
        """(k,) coordinates of a tangent dy at y in `tangent_basis(y)`."""
        raise NotImplementedError

    def rigid_start_tangent(self, y0, q):
        """The start-state tangent that moves `rigid_transport`'s output as a longer rigid
        part does: d rigid_transport(y0, q) / d q[1] = D_y0 rigid_transport . this (the
        position along the tangent t, the force by -f, the moment by -t x n0)."""
        raise NotImplementedError


def stiffness_rows(model, table, columns):
    """(S, samples * n_stiff) stiffness part of the parameter rows."""
    k = table.stiffness[:, :, list(columns)]  # (S, 4, n_stiff): samples at TAPER_NODES
    if not model.tapered:
        k = k[:, :1]
    return k.reshape(k.shape[0], -1)


def stiffness_at(model, flat, tau):
    """The stiffnesses at tau: the one sample, or the samples interpolated when tapered."""
    if not model.tapered:
        return flat
    samples = flat.reshape(4, model.n_stiff)
    return _lagrange_weights(tau) @ samples
