"""Fixed-step integration of one segment's flow: the `Integrator` (a diffrax explicit
Runge-Kutta solver, the steps per segment, and how the steps are driven).

A segment's first `rigid` millimetres are transported in closed form by the rod model; the
rest is integrated in tau in [0, 1] at `steps` equal steps. Three backends drive the
steps; each is a final class:

- `TableauBackend` (default) reads the solver's Butcher tableau and writes the stages out
  in a `lax.scan`: for these tiny states it compiles and runs several times faster than
  the solver's own step, and gives the same answer.
- `StepBackend` calls the solver's `step` in a `lax.scan` (any diffrax solver).
- `DiffeqsolveBackend` calls `diffrax.diffeqsolve` with constant steps. It cannot
  re-project the state after each step (the rod model's `after_step`: the planar
  (cos, sin) pair, the 3-D frame), so its answer differs by the integration error.
"""

import abc
import numbers
from typing import ClassVar

import diffrax as dfx
import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax

from ._choices import choice


def rk_step(tableau, rhs, t, y, h):
    """One explicit Runge-Kutta step of dy/dt = rhs(t, y) from a diffrax Butcher tableau."""
    b = np.asarray(tableau.b_sol)
    c = np.asarray(tableau.c)
    n_stages = int(np.max(np.nonzero(b)[0])) + 1  # stages past the last weight are unused
    ks = [rhs(t, y)]
    for i in range(1, n_stages):
        a = np.asarray(tableau.a_lower[i - 1])
        yi = y + h * sum(float(aj) * k for aj, k in zip(a, ks) if aj != 0.0)
        ks.append(rhs(t + float(c[i - 1]) * h, yi))
    return y + h * sum(float(bi) * k for bi, k in zip(b, ks) if bi != 0.0)


def _with_start(y, y_end, ys, save_all):
    return jnp.concatenate([y[None], ys], axis=0) if save_all else y_end


class AbstractBackend(eqx.Module):
    """How an integrator's steps are driven; `name` is its word in solver files."""

    name: ClassVar[str]

    def check(self, solver) -> None:
        """Raise ValueError if this backend cannot drive `solver`."""

    @abc.abstractmethod
    def run(self, model, solver, flex, y, q, n: int, save_all: bool):
        """Integrate flex * model.rhs from y over tau in [0, 1] at n steps: the end state,
        or (save_all) the n + 1 states at the step points."""


class TableauBackend(AbstractBackend):
    """Stages written out from the solver's Butcher tableau, in a `lax.scan`."""

    name: ClassVar[str] = "tableau"

    def check(self, solver):
        if getattr(solver, "tableau", None) is None:
            raise ValueError(
                f"Integrator.solver {type(solver).__name__} has no Butcher tableau; use an "
                "explicit Runge-Kutta solver (Tsit5, Dopri5, Bosh3, Heun, ...) or "
                "backend=StepBackend()"
            )

    def run(self, model, solver, flex, y, q, n, save_all):
        h = 1.0 / n
        f = lambda t, yy: flex * model.rhs(t, yy, q)

        def rk(yy, i):
            y1 = model.after_step(yy, rk_step(solver.tableau, f, i * h, yy, h))
            return y1, (y1 if save_all else None)

        y_end, ys = lax.scan(rk, y, jnp.arange(n, dtype=q.dtype))
        return _with_start(y, y_end, ys, save_all)


class StepBackend(AbstractBackend):
    """The diffrax solver's own `step`, in a `lax.scan`."""

    name: ClassVar[str] = "step"

    def run(self, model, solver, flex, y, q, n, save_all):
        h = 1.0 / n
        term = dfx.ODETerm(lambda t, yy, args: flex * model.rhs(t, yy, args))
        state = solver.init(term, 0.0, h, y, q)

        def body(carry, i):
            yy, st = carry
            t0 = i * h
            y1, _, _, st, _ = solver.step(term, t0, t0 + h, yy, q, st, made_jump=False)
            y1 = model.after_step(yy, y1)
            return (y1, st), (y1 if save_all else None)

        (y_end, _), ys = lax.scan(body, (y, state), jnp.arange(n, dtype=q.dtype))
        return _with_start(y, y_end, ys, save_all)


class DiffeqsolveBackend(AbstractBackend):
    """`diffrax.diffeqsolve` at constant steps (no re-projection after each step)."""

    name: ClassVar[str] = "diffeqsolve"

    def run(self, model, solver, flex, y, q, n, save_all):
        term = dfx.ODETerm(lambda t, yy, args: flex * model.rhs(t, yy, args))
        ts = jnp.linspace(0.0, 1.0, n + 1)
        saveat = dfx.SaveAt(ts=ts) if save_all else dfx.SaveAt(t1=True)
        sol = dfx.diffeqsolve(
            term,
            solver,
            0.0,
            1.0,
            1.0 / n,
            y,
            args=q,
            saveat=saveat,
            stepsize_controller=dfx.ConstantStepSize(),
            max_steps=n,
            adjoint=dfx.ForwardMode(),
            throw=False,
        )
        return sol.ys if save_all else sol.ys[-1]


BACKENDS = {kind.name: kind() for kind in (TableauBackend, StepBackend, DiffeqsolveBackend)}


def as_backend(value) -> AbstractBackend:
    """`Integrator.backend` as its object (a name is deprecated, see `choice`)."""
    return choice(value, "Integrator.backend", AbstractBackend, BACKENDS, ValueError)


class Integrator(eqx.Module):
    """Fixed-step integration of each segment.

    solver: a diffrax explicit Runge-Kutta solver (default Tsit5).
    steps: steps per segment (fixes shapes; changing it recompiles).
    backend: how the steps are driven: TableauBackend() (default), StepBackend() or
        DiffeqsolveBackend() (see the module docstring).
    """

    solver: dfx.AbstractSolver = dfx.Tsit5(scan_kind="lax")
    steps: int = eqx.field(static=True, default=10)
    backend: AbstractBackend = eqx.field(
        static=True, default=TableauBackend(), converter=as_backend
    )

    def __check_init__(self):
        if not isinstance(self.steps, numbers.Integral) or self.steps < 1:
            raise ValueError(f"Integrator.steps must be a positive integer, got {self.steps!r}")
        self.backend.check(self.solver)


def integrate(model, integrator: Integrator, y0, q, save_all: bool):
    """Integrate one segment: closed-form rigid part, then fixed-step RK in tau in [0, 1]."""
    y = model.rigid_transport(y0, q)
    flex = q[0] - q[1]
    return integrator.backend.run(model, integrator.solver, flex, y, q, integrator.steps, save_all)
