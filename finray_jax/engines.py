"""Where the work of a sweep or a clamp study runs: in this process (`LocalEngine`, the
default) or as tasks on a Ray cluster (`RayEngine`).

An engine maps a work function over items, `engine.map_unordered(work, shared, items)`,
and yields one `Landed` per item as it finishes, in any order. `work(shared, item)` is a
module-level function (a worker imports it by name); `shared` is what every item needs
(the sweep, its finger), sent to each worker once. A work function that keeps prepared
state (a compiled program) keeps it per process, so every worker compiles once.

The engine never writes files: the caller (the driver) writes each result as it lands.
Ray is imported by `RayEngine` alone, when it runs; `pip install 'finray_jax[ray]'`
installs it. docs/distributed.md shows a cluster at work.
"""

from __future__ import annotations

import dataclasses
import os
import socket
import time
from collections.abc import Callable, Iterable, Iterator

__all__ = ["EngineError", "Landed", "LocalEngine", "RayEngine", "engine_named"]

RAY_HINT = "pip install 'finray_jax[ray]'"


class EngineError(ValueError):
    """An engine that cannot run: a bad setting (named with its value) or Ray missing."""


@dataclasses.dataclass(frozen=True)
class Landed:
    """One item's outcome. error: None when work returned `value`, else why its task
    failed for good (its worker died more often than the retries allow, or it raised).
    worker: the process that ran it ("host:pid"); seconds: its run time there; first:
    the first item that process ran for this work function (its compile included)."""

    item: object
    value: object = None
    error: str | None = None
    worker: str = ""
    seconds: float = 0.0
    first: bool = False


# Work functions a process has run already (the `first` of Landed).
_RAN: set[str] = set()


def run_item(work: Callable, shared, item) -> tuple[object, str, float, bool]:
    """work(shared, item) in this process, timed: (value, worker, seconds, first)."""
    key = f"{work.__module__}.{work.__qualname__}"
    first = key not in _RAN
    t0 = time.perf_counter()
    value = work(shared, item)
    _RAN.add(key)
    return value, f"{socket.gethostname()}:{os.getpid()}", time.perf_counter() - t0, first


@dataclasses.dataclass(frozen=True)
class LocalEngine:
    """Items one after another in this process (an exception in work propagates)."""

    name = "local"

    @property
    def workers(self) -> int:
        return 1

    def describe(self) -> str:
        return "this process"

    def map_unordered(self, work: Callable, shared, items: Iterable) -> Iterator[Landed]:
        for item in items:
            value, worker, seconds, first = run_item(work, shared, item)
            yield Landed(item, value, None, worker, seconds, first)


def _positive_int(name: str, value, allow_none: bool = True):
    if value is None and allow_none:
        return
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise EngineError(f"{name} must be a positive integer, got {value!r}")


@dataclasses.dataclass(frozen=True)
class RayEngine:
    """Items as Ray Core tasks, at most `workers` at a time.

    address: a running cluster ("auto": the one this machine belongs to, or
        "HOST:PORT" of its head); None: $RAY_ADDRESS if set, else a Ray instance started
        on this machine for this run (and stopped after it).
    workers: tasks running at once (None: as many as the cluster's CPUs (or GPUs, with
        task_gpus) allow).
    task_cpus, task_gpus: what each task asks of its node (a GPU task finds its GPU as
        JAX's default device).
    cache_dir: JAX's persistent compilation cache for the workers, e.g. on storage every
        node shares, so that a worker loads what another compiled (None: each worker's
        own $FINRAY_CACHE_DIR or default).
    max_retries: how often Ray re-runs a task whose worker process died (killed, out of
        memory, node lost); after that the item lands with its error.
    """

    address: str | None = None
    workers: int | None = None
    task_cpus: float = 1.0
    task_gpus: float = 0.0
    cache_dir: str | None = None
    max_retries: int = 3

    name = "ray"

    def __post_init__(self):
        _positive_int("workers", self.workers)
        for key in ("task_cpus", "task_gpus"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
                raise EngineError(f"{key} must be a non-negative number, got {v!r}")
        if not (self.task_cpus > 0 or self.task_gpus > 0):
            raise EngineError("a task must ask for CPUs or GPUs: task_cpus and task_gpus are 0")
        if not isinstance(self.max_retries, int) or self.max_retries < 0:
            raise EngineError(f"max_retries must be a whole number >= 0, got {self.max_retries!r}")
        if self.address is not None and not str(self.address).strip():
            raise EngineError(f"address must be 'auto' or HOST:PORT, got {self.address!r}")

    def describe(self) -> str:
        where = self.address or os.environ.get("RAY_ADDRESS") or "a Ray instance on this machine"
        return f"Ray ({where})"

    def map_unordered(self, work: Callable, shared, items: Iterable) -> Iterator[Landed]:
        from . import _ray_tasks  # (imports ray)

        return _ray_tasks.map_unordered(self, work, shared, items)


def require_ray() -> None:
    """Import Ray, or raise an EngineError that says how to install it."""
    try:
        import ray  # noqa: F401
    except ImportError:
        raise EngineError(
            f"the ray engine needs Ray, which is not installed here: {RAY_HINT}"
        ) from None


def engine_named(name: str, **settings):
    """The engine called `name` ("local" or "ray") with the given settings."""
    if name == "local":
        extra = {k: v for k, v in settings.items() if v is not None}
        if extra:
            raise EngineError(
                f"{', '.join(sorted(extra))}: settings of the ray engine, not of the local one"
            )
        return LocalEngine()
    if name == "ray":
        return RayEngine(**{k: v for k, v in settings.items() if v is not None})
    raise EngineError(f"engine must be 'local' or 'ray', got {name!r}")
