"""Batches of grasps: every design of a finger closed on its objects, one design after
another on the base finger's segment table, and yielded chunk by chunk as `BatchResult`s
(what a sweep of a finger file with objects and a [grasp] table runs)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from ._batch_data import INVALID, BatchResult, Diagnosis, check_values, chunk_result
from ._finger import Finger, FingerError
from ._grasp import grasp
from ._release import release_force
from ._solve import topology_of
from .design import (
    GRASP_OUTPUTS,
    OUTPUTS,
    RELEASE_OUTPUTS,
    DesignError,
    design_valid_jit,
    set_design,
)


def iter_grasps(
    base_finger: Finger,
    values: Mapping[str, np.ndarray],
    outputs: Sequence[str] = ("contact.normal_force",),
    *,
    grasp_kwargs: Mapping,
    release_kwargs: Mapping | None = None,
    mode: str = "planar",
    chunk_size: int = 16,
    start: int = 0,
    topology=None,
) -> Iterator[tuple[int, BatchResult]]:
    """Grasp designs start, start + 1, ... of a finger with objects, one after another,
    and yield (first index, BatchResult) every `chunk_size` designs.

    Each design is closed on its objects as `finray_jax.grasp(finger, **grasp_kwargs)`
    does (a path of warm-started solves; `grasp_kwargs` as `GraspSettings.grasp_kwargs()`:
    closing or actuator_force, direction, symmetric), on the base finger's segment table
    (`grasp(topology=)`; or on `topology`, that of `topology_of(base_finger, mode)` made
    before), so every design shares one compiled program. outputs: names of
    `design.GRASP_OUTPUTS` (the contact), `design.RELEASE_OUTPUTS` (the holding force:
    each converged grasp is then also pulled out, `release_force(g, **release_kwargs)`, on
    the same segment table) or `design.OUTPUTS` (of the grasp's equilibrium).
    A design that is invalid, leaves the base topology or moves its objects out of reach
    is `invalid`; a grasp that does not converge is `failed` with the solver's result.
    """
    arrays, size = check_values(base_finger, values)
    outputs = tuple(outputs)
    for name in outputs:
        if name not in GRASP_OUTPUTS and name not in RELEASE_OUTPUTS and name not in OUTPUTS:
            raise DesignError(
                f"unknown output {name!r}; valid outputs: {', '.join(GRASP_OUTPUTS)}, "
                f"{', '.join(RELEASE_OUTPUTS)}, {', '.join(OUTPUTS)}"
            )
    pulled = any(name in RELEASE_OUTPUTS for name in outputs)
    release_kwargs = dict(release_kwargs or {})
    if not isinstance(chunk_size, int) or isinstance(chunk_size, bool) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    kwargs = dict(grasp_kwargs)
    topo = topology_of(base_finger, mode) if topology is None else topology
    diagnosis = Diagnosis(base_finger, topo.mode, topo)
    for a in range(start, size, chunk_size):
        z = min(a + chunk_size, size)
        outs = {k: np.full(z - a, np.nan) for k in outputs}
        code = np.full(z - a, INVALID, dtype=np.int64)
        its = np.zeros(z - a, dtype=np.int64)
        res = np.full(z - a, np.nan)
        for i in range(a, z):
            finger = set_design(base_finger, {k: v[i] for k, v in arrays.items()})
            if not bool(design_valid_jit(finger, topo)):
                continue
            try:
                g = grasp(finger, mode=mode, topology=topo, **kwargs)
            except FingerError:  # (its objects out of reach, or behind the finger)
                continue
            j = i - a
            code[j] = int(g.solution.result._value)
            its[j] = int(g.solution.iterations)
            res[j] = float(g.solution.max_residual)
            if g.converged:
                trace = release_force(g, topology=g.topology, **release_kwargs) if pulled else None
                for name in outputs:
                    outs[name][j] = float(_output(name, g, trace))
        yield a, chunk_result(arrays, slice(a, z), outs, code, its, res, diagnosis)


def _output(name: str, g, trace):
    """Output `name` of a converged grasp g (and of its release trace, when pulled)."""
    if name in RELEASE_OUTPUTS:
        return RELEASE_OUTPUTS[name](trace)
    if name in GRASP_OUTPUTS:
        return GRASP_OUTPUTS[name](g)
    return OUTPUTS[name](g.solution, g.finger)
