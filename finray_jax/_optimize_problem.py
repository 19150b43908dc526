"""The problem an optimisation file describes (`OptimizeProblem`): the base finger, the
objects, the objective, the optimised design values (`DesignVar`) and their bounds, the
constraints and the optimiser's settings."""

from __future__ import annotations

import dataclasses

import numpy as np

from . import io as fio
from ._finger import Finger
from ._objective import CONSTRAINTS
from .design import set_design as _set_design
from .studies import with_object


@dataclasses.dataclass(frozen=True)
class DesignVar:
    """One optimised design value, kept in [lo, hi] (initial: the finger's value)."""

    name: str
    lo: float
    hi: float
    initial: float


@dataclasses.dataclass(frozen=True)
class OptimizeProblem:
    """A parsed optimisation file (see docs/optimize-format.md)."""

    source: str
    finger_path: str
    finger: Finger
    settings: fio.SolveSettings
    objective: str = "contact_force"
    friction: float = 0.0
    closing: float = 6.0
    direction: tuple = (-1.0, 0.0)
    pull_direction: tuple = (0.0, 1.0)
    symmetric: bool = True
    pull_step: float = 2.0
    diameters: tuple | None = None
    object_height: float = 60.0
    clearance: float = 0.5
    aggregate: str = "mean"
    temperature: float = 0.02
    design: tuple = ()
    constraints: dict = dataclasses.field(default_factory=dict)
    optimizer: str = "adam"
    learning_rate: float = 0.1
    iterations: int = 30
    tolerance: float = 1e-4
    patience: int = 3
    penalty_weight: float = 100.0
    penalty_shift: float = 0.01
    digest: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.design)

    @property
    def lo(self) -> np.ndarray:
        return np.asarray([d.lo for d in self.design], float)

    @property
    def hi(self) -> np.ndarray:
        return np.asarray([d.hi for d in self.design], float)

    @property
    def x0(self) -> np.ndarray:
        return np.asarray([d.initial for d in self.design], float)

    def object_fingers(self) -> list[Finger]:
        """The base finger of every object (its design values at the initial design)."""
        base = _set_design(self.finger, dict(zip(self.names, self.x0.tolist())))
        if self.diameters is None:
            return [base]
        return [
            with_object(base, d, height=self.object_height, clearance=self.clearance)
            for d in self.diameters
        ]

    def active_constraints(self) -> tuple[str, ...]:
        n_cb = self.finger.n_crossbeams
        out = [c for c in CONSTRAINTS if c in self.constraints]
        if n_cb >= 2 and any(n.startswith("crossbeams.") for n in self.names):
            out.append("crossing")  # always, when the layout moves
        return tuple(c for c in CONSTRAINTS if c in out)

    def designed(self, x) -> Finger:
        """The base finger with design values x (one per [[design]] entry)."""
        return _set_design(self.finger, dict(zip(self.names, np.asarray(x, float).tolist())))
