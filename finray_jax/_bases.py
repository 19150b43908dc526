"""How the mounting adaptor holds a main beam's base: clamped, pinned or free.

Each kind is a final class that writes its own boundary rows of the shooting residual
and says which rigid-body freedoms it fixes (for the stability analysis). A finger holds
instances (`Adaptor(front_base=PinnedBase())`); finger files name them by `name`.
"""

import abc
from typing import ClassVar

import equinox as eqx

from ._choices import choice


class AbstractBase(eqx.Module):
    """A main beam's base condition. `name` is its word in finger files; `fixed` says
    which of the base node's (x, z, rotation about y) freedoms it holds."""

    name: ClassVar[str]
    fixed: ClassVar[tuple[bool, bool, bool]]
    holds_clamp: ClassVar[bool] = False  # a rigidly clamped length may start here

    @abc.abstractmethod
    def rows(self, model, y, point, theta, F, L):
        """Residual rows at the beam's first state y: the base at `point` with undeformed
        angle `theta`; F and L scale forces and lengths."""

    def __str__(self) -> str:
        return self.name


class ClampedBase(AbstractBase):
    """Position and orientation held: the original adaptor, and the modified adaptor's
    back beam."""

    name: ClassVar[str] = "clamped"
    fixed: ClassVar[tuple[bool, bool, bool]] = (True, True, True)
    holds_clamp: ClassVar[bool] = True

    def rows(self, model, y, point, theta, F, L):
        return [model.position_rows(y, point, L), model.orientation_rows(y, theta)]


class PinnedBase(AbstractBase):
    """Position held, free to turn about the out-of-plane axis: the modified adaptor's
    released front beam."""

    name: ClassVar[str] = "pinned"
    fixed: ClassVar[tuple[bool, bool, bool]] = (True, True, False)

    def rows(self, model, y, point, theta, F, L):
        return [model.position_rows(y, point, L), model.hinge_rows(y, theta, F, L)]


class FreeBase(AbstractBase):
    """Nothing held: the base carries no force and no moment."""

    name: ClassVar[str] = "free"
    fixed: ClassVar[tuple[bool, bool, bool]] = (False, False, False)

    def rows(self, model, y, point, theta, F, L):
        return [model.force_rows(model.force(y), F), model.moment_rows(model.moment(y), F, L)]


BASES = {kind.name: kind() for kind in (ClampedBase, PinnedBase, FreeBase)}


def as_base(value, field: str) -> AbstractBase:
    """An adaptor field's value as a base object (a name is deprecated, see `choice`)."""
    return choice(value, field, AbstractBase, BASES)
