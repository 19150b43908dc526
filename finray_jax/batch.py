"""Batches of designs: one base finger, many values of named design values, solved in
fixed-size chunks by one compiled program each (`jax.vmap` over the designs, or
`lax.map`; sharded over the devices when there are several).

Every design of a batch shares the base finger's topology (number of crossbeams, order of
attachments and load points, boundary kinds), so new values never recompile. A design
that breaks that topology or is invalid (NaN, non-positive thickness, attachment outside
its beam, ...) is flagged "invalid" and not solved (the base finger is solved in its slot
and discarded); a design whose solve fails or lies beyond the limit load is flagged by
its own status. The solver's loops are bounded, so no member stalls the batch, and
members never mix: the others come out as if solved alone.

Like `solve_finger` on one finger, each chunk is first solved by Newton at full load;
only the designs that this does not solve (large loads, folds) go on to arc-length
continuation, in sub-batches of `continuation_chunk_size`, so that one hard design does
not make a whole vmapped chunk (which runs in lock step) continue.
On CPU the designs of a chunk are by default mapped one after another inside the
compiled program instead of vmapped: faster there, and safe from a deadlock of jaxlib's
batched CPU LAPACK kernels (see `_vectorize`).

A batch's data (values in, `BatchResult` out) is in `_batch_data`; batches of grasps
(`iter_grasps`) are in `_grasp_batch`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterator, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from . import _solve
from ._batch_data import INVALID, BatchResult, Diagnosis, check_values, chunk_result, pad
from ._batch_data import one_line as one_line
from ._batch_data import status_names as status_names
from ._finger import Finger
from ._grasp_batch import iter_grasps as iter_grasps
from ._integrator import Integrator
from ._solution import RESULTS, Solution
from ._solve import SolverOptions, solve_finger, topology_of
from .design import check_output_names, design_valid, evaluate_outputs, get_design, set_design

__all__ = [
    "BatchResult",
    "Diagnosis",
    "INVALID",
    "iter_batch",
    "iter_grasps",
    "solve_batch",
    "status_names",
]

_AXIS = "design"


# --------------------------------------------------------------------------------------
# The jitted core
# --------------------------------------------------------------------------------------


def _prepare(topo, base: Finger, values):
    finger = set_design(base, values)
    ok = design_valid(finger, topo)
    # An invalid design is replaced by the base finger (solved, then discarded), so it
    # cannot feed NaN or a broken geometry to the solver.
    return jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), finger, base), ok


def _direct(topo, integrator, options, outputs, base: Finger, init, values):
    """Newton at full load (as `solve_finger` tries first), from the undeformed state or
    from the base solution's deformation `init` (shared by the batch) carried onto the
    design's own undeformed shape."""
    finger, valid = _prepare(topo, base, values)
    if init is not None:
        init = _solve.start_from_deformation(topo, finger, init)
    sol, ok, _ = _solve.direct_core(topo, integrator, options, finger, init)
    return _pack(sol, finger, outputs, valid), ok & valid


def _full(topo, integrator, options, outputs, base: Finger, init, values):
    """Arc-length continuation (and the fold), for designs whose direct solve failed
    (from the undeformed state: `init` is not used)."""
    del init
    finger, valid = _prepare(topo, base, values)
    sol = solve_finger(finger, integrator=integrator, options=options, topology=topo)
    return _pack(sol, finger, outputs, valid)


def _pack(sol, finger, outputs, valid):
    code = jnp.where(valid, sol.result._value, INVALID)
    failed = (code != RESULTS.successful._value) & (code != RESULTS.beyond_limit_load._value)
    outs = evaluate_outputs(sol, finger, outputs)
    outs = {k: jnp.where(failed, jnp.nan, v) for k, v in outs.items()}
    its = jnp.where(valid, sol.iterations, 0)
    return outs, code, its, jnp.where(valid, sol.max_residual, jnp.nan)


_traces = 0  # how often a chunk program was traced (a test checks values never retrace)


def _vectorize(stage, mesh, platform: str, requested: bool | None) -> bool:
    """vmap the designs of a chunk (True), or `lax.map` over them one after another.

    Default (requested None): vmap on accelerators, map on CPU, where a vmapped chunk is
    slower per design than one design after another (benchmarks/README.md, `batch.py`).
    Map is also forced where vmap can hang on CPU: jaxlib 0.10's
    CPU LAPACK kernels split a batched factorisation over the intra-op thread pool and
    block until the pieces are done, so two of them at once (both branches of the vmapped
    `lax.cond` of the continuation stage, or one per device when several CPU devices
    share the pool) can hold every pool thread (the hung stacks wait in
    `jax::ParallelBatchMap`). The direct Newton stage factorises one
    matrix at a time and may be vmapped on one CPU device.
    """
    if platform != "cpu":
        return True if requested is None else requested
    return bool(requested) and stage is _direct and mesh is None


@eqx.filter_jit
def _chunk_core(
    stage, topo, integrator, options, outputs, mesh, vectorize, base: Finger, init, values
):
    global _traces
    _traces += 1
    one = functools.partial(stage, topo, integrator, options, outputs)
    if vectorize:
        fn = jax.vmap(one, in_axes=(None, None, 0))
    else:
        fn = lambda b, i, v: lax.map(lambda x: one(b, i, x), v)
    if mesh is None:
        return fn(base, init, values)
    # Each device runs its own loops on its rows (no lock step across devices).
    # check_vma=False: the solver's loop carries start replicated and become per-row.
    spec = PartitionSpec(_AXIS)
    return jax.shard_map(
        fn,
        mesh=mesh,
        in_specs=(PartitionSpec(), PartitionSpec(), spec),
        out_specs=spec,
        check_vma=False,
    )(base, init, values)


# --------------------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------------------


def _init_deformation(init, topo):
    """The shared start of a batch's Newton solves: the deformation init carries (a
    Solution of the base finger: `Solution.deformation`), or None."""
    if init is None:
        return None
    if not isinstance(init, Solution):
        raise TypeError(f"init must be a Solution of the base finger, got {type(init).__name__}")
    y = np.asarray(init.unknowns, dtype=np.float64)
    n = topo.n_segments * topo.model.n_unknown
    if init.mode != topo.mode or y.shape != (n,):
        raise ValueError(
            f"init is a {init.mode} solution with {y.size} unknowns; the batch's topology is "
            f"{topo.mode} with {n}: pass a Solution of the base finger in the batch's mode"
        )
    # (Not its Jacobian's factors, `Solution.jacobian`: a batch's designs lie too far from
    # the base for chord steps on them to pay (benchmarks/README.md, `batch.py`).)
    return jnp.asarray(init.deformation)


def _default_device():
    """The device jax puts new arrays and computations on (`jax_default_device`, a
    device or a platform name, else the first device)."""
    d = jax.config.jax_default_device
    if d is None:
        return jax.devices()[0]
    return jax.devices(d)[0] if isinstance(d, str) else d


def _placement(devices):
    """(mesh, target, platform): a mesh over several devices (target: the sharding of a
    chunk's rows over it), or None and the one device (target: that device). devices
    None: every device of the default device's platform (on a GPU machine whose default
    device was set to the CPU, the CPU)."""
    if devices is None:
        devices = jax.devices(_default_device().platform)
    devices = list(devices)
    if not devices:
        raise ValueError("devices must name at least one device, got an empty list")
    if len(devices) == 1:
        return None, devices[0], devices[0].platform
    mesh = Mesh(np.asarray(devices), (_AXIS,))
    return mesh, NamedSharding(mesh, PartitionSpec(_AXIS)), devices[0].platform


# The chunk size by platform when none is given: a CPU maps the designs one after
# another, so a chunk only bounds memory and the loss of an interrupted sweep; an
# accelerator vmaps them, and a larger chunk keeps it busier: 4,096 designs gives the best
# throughput among the chunk sizes in benchmarks/README.md (`batch_gpu.py`).
def default_chunk_size(platform: str) -> int:
    return 256 if platform == "cpu" else 4096


def chunk_size_here() -> int:
    """The default chunk size on the device this process solves on (`jax_default_device`)."""
    return default_chunk_size(_default_device().platform)


def iter_batch(
    base_finger: Finger,
    values: Mapping[str, np.ndarray],
    outputs: Sequence[str] = ("tip.dx",),
    *,
    mode: str = "planar",
    chunk_size: int | None = None,
    continuation_chunk_size: int = 8,
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    topology=None,
    start: int = 0,
    devices=None,
    vectorize: bool | None = None,
    init: Solution | None = None,
) -> Iterator[tuple[int, BatchResult]]:
    """Solve designs start, start + 1, ... chunk by chunk; yield (first index, BatchResult).

    See `solve_batch`. Every chunk is padded to the same size, so all chunks share one
    compiled program.
    """
    arrays, size = check_values(base_finger, values)
    outputs = tuple(outputs)
    check_output_names(outputs)
    mesh, target, platform = _placement(devices)
    if chunk_size is None:
        chunk_size = default_chunk_size(platform)
    for name, n in (
        ("chunk_size", chunk_size),
        ("continuation_chunk_size", continuation_chunk_size),
    ):
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise ValueError(f"{name} must be a positive integer, got {n!r}")
    topo = topology_of(base_finger, mode) if topology is None else topology
    n_dev = 1 if mesh is None else mesh.size
    fill = {k: np.asarray(v) for k, v in get_design(base_finger, list(arrays)).items()}
    continuation = dataclasses.replace(options, direct_first=False)
    y0 = _init_deformation(init, topo)
    diagnosis = Diagnosis(base_finger, topo.mode, topo)
    if y0 is not None and mesh is None:  # (on the chunk's device, wherever init was)
        y0 = jax.device_put(y0, target)

    def run(stage, opts, rows, n_rows):
        padded = -(-n_rows // n_dev) * n_dev
        chunk = jax.device_put(pad(arrays, rows, padded, fill), target)
        vec = _vectorize(stage, mesh, platform, vectorize)
        if vec:  # a vmapped lax.cond runs both branches: chord steps would save nothing
            opts = dataclasses.replace(opts, reuse_jacobian=False)
        out = _chunk_core(stage, topo, integrator, opts, outputs, mesh, vec, base_finger, y0, chunk)
        return jax.tree_util.tree_map(np.asarray, out)

    for a in range(start, size, chunk_size):
        z = min(a + chunk_size, size)
        n = z - a
        if options.direct_first:
            (outs, code, its, res), ok = run(_direct, options, slice(a, z), chunk_size)
            redo = np.flatnonzero(~ok[:n] & (code[:n] != INVALID))
        else:
            outs, code, its, res = run(_full, options, slice(a, z), chunk_size)
            redo = np.zeros(0, dtype=np.int64)
        outs = {k: v[:n].copy() for k, v in outs.items()}
        code, its, res = code[:n].astype(np.int64), its[:n].astype(np.int64), res[:n].copy()
        # Designs whose direct Newton failed: continuation, a few at a time (the batch
        # runs in lock step, so the slowest member sets the pace of its sub-batch).
        m = continuation_chunk_size
        for b in range(0, redo.size, m):
            sel = redo[b : b + m]
            o2, c2, i2, r2 = run(_full, continuation, a + sel, m)
            k = sel.size
            for name in outs:
                outs[name][sel] = o2[name][:k]
            code[sel], its[sel], res[sel] = c2[:k], its[sel] + i2[:k], r2[:k]
        yield a, chunk_result(arrays, slice(a, z), outs, code, its, res, diagnosis)


def solve_batch(
    base_finger: Finger,
    values: Mapping[str, np.ndarray],
    outputs: Sequence[str] = ("tip.dx",),
    *,
    mode: str = "planar",
    chunk_size: int | None = None,
    continuation_chunk_size: int = 8,
    integrator: Integrator = Integrator(),
    options: SolverOptions = SolverOptions(),
    topology=None,
    devices=None,
    vectorize: bool | None = None,
    init: Solution | None = None,
) -> BatchResult:
    """Solve many designs of one finger: `values` maps design-value names (see
    `finray_jax.design`) to arrays with one row per design; `outputs` names the scalar
    outputs to return.

    Designs are solved `chunk_size` at a time in one compiled program (bounded memory; the
    same program for every chunk and every set of values; default 256 on a CPU, 4096 on an
    accelerator), on `devices` (default: every device of the default device's platform),
    sharded over them when there are several; designs whose direct Newton
    solve fails are continued `continuation_chunk_size` at a time (a second program,
    compiled on first need). vectorize: True to `jax.vmap` the designs of a chunk, False
    to `lax.map` them one after another; None (default) vmaps on accelerators and maps on
    CPU, where that is faster (see `_vectorize`; on CPU only the direct stage on one
    device can be vmapped; a vmapped chunk takes no chord steps, as if
    options.reuse_jacobian were False). mode: "planar" or "spatial" ("auto" resolves on the base
    finger). init: a Solution of the base finger (same topology and mode) whose
    deformation (each segment's displacement, rotation and internal wrench) starts every
    design's Newton solve, carried onto the design's own undeformed shape: fewer
    iterations for designs near the base (a design it does not solve is continued from the
    undeformed shape as usual). Returns a BatchResult with per-design status.
    """
    parts = [
        r
        for _, r in iter_batch(
            base_finger,
            values,
            outputs,
            mode=mode,
            chunk_size=chunk_size,
            continuation_chunk_size=continuation_chunk_size,
            integrator=integrator,
            options=options,
            topology=topology,
            devices=devices,
            vectorize=vectorize,
            init=init,
        )
    ]
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros((0,))
    return BatchResult(
        inputs={k: cat([p.inputs[k] for p in parts]) for k in values},
        outputs={k: cat([p.outputs[k] for p in parts]) for k in outputs},
        result=cat([p.result for p in parts]).astype(np.int64),
        iterations=cat([p.iterations for p in parts]).astype(np.int64),
        max_residual=cat([p.max_residual for p in parts]),
        diagnosis=parts[0].diagnosis if parts else None,
    )
