"""`RayEngine`: the items of a sweep or a study as Ray Core tasks on a cluster. It
connects to (or starts) the cluster, keeps `workers` tasks running and yields each as it
lands. Ray is imported when a RayEngine runs, never before."""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable, Iterable, Iterator

from ._cache import enable_compilation_cache
from ._engine_core import EngineError, Landed, require_ray, run_item


def _ray():
    """The ray module (an EngineError, saying how to install it, when it is missing)."""
    require_ray()
    import ray
    import ray.exceptions

    return ray


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
        """Each item as a task, `workers` at a time, yielded as it lands (see the class)."""
        return _map_unordered(self, work, shared, items)


_WAIT_S = 0.25  # how long the driver blocks in ray.wait (so that Ctrl-C is seen at once)
_prepared = False  # this worker process has set its compilation cache


def _task(work: Callable, shared, item):
    """What a Ray task runs: work(shared, item) in a worker process, timed."""
    global _prepared
    if not _prepared:
        enable_compilation_cache()  # ($FINRAY_CACHE_DIR as the engine's cache_dir sets it)
        _prepared = True
    return run_item(work, shared, item)


def _connect(engine: RayEngine) -> bool:
    """Connect this process to the engine's cluster; True when this run started it (or
    connected) and so disconnects after it, False when Ray was already initialised."""
    ray = _ray()
    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    quiet = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    address = engine.address or os.environ.get("RAY_ADDRESS")
    try:
        if address:
            ray.init(address=address, **quiet)
        else:  # (a Ray instance of this machine for this run)
            cpus = None if engine.workers is None else engine.workers * engine.task_cpus
            ray.init(num_cpus=cpus, **quiet)
    except (ConnectionError, RuntimeError, ValueError) as e:
        text = " ".join(str(e).split())
        where = address or "this machine"
        raise EngineError(f"cannot connect to the Ray cluster at {where}: {text}") from None
    return True


def _env(engine: RayEngine) -> dict:
    """The workers' environment variables: the compilation cache's settings (the engine's
    cache_dir, else this process's FINRAY_NO_CACHE)."""
    if engine.cache_dir is not None:
        path = os.path.abspath(os.path.expanduser(engine.cache_dir))
        return {"FINRAY_CACHE_DIR": path, "FINRAY_NO_CACHE": "0"}
    if os.environ.get("FINRAY_NO_CACHE"):
        return {"FINRAY_NO_CACHE": os.environ["FINRAY_NO_CACHE"]}
    return {}


def concurrency(engine: RayEngine) -> int:
    """Tasks to keep running: engine.workers, else what the cluster's resources allow."""
    if engine.workers is not None:
        return engine.workers
    have = _ray().cluster_resources()
    n = []
    if engine.task_cpus > 0:
        n.append(int(have.get("CPU", 0) // engine.task_cpus))
    if engine.task_gpus > 0:
        n.append(int(have.get("GPU", 0) // engine.task_gpus))
    if min(n) < 1:
        raise EngineError(
            f"the Ray cluster has {have.get('CPU', 0):g} CPUs and {have.get('GPU', 0):g} GPUs: not "
            f"enough for one task of {engine.task_cpus:g} CPUs and {engine.task_gpus:g} GPUs"
        )
    return min(n)


def _failure(e: BaseException) -> str:
    """Why a task failed for good, in one line."""
    ray = _ray()
    if isinstance(e, ray.exceptions.RayTaskError):
        cause = e.cause if e.cause is not None else e
        text = f"{type(cause).__name__}: {cause}"
    elif isinstance(e, ray.exceptions.OutOfMemoryError):
        text = "its worker ran out of memory"
    elif isinstance(e, ray.exceptions.WorkerCrashedError):
        text = "its worker process died (more often than the retries allow)"
    else:
        text = f"{type(e).__name__}: {e}"
    return " ".join(text.split())[:400]


def _map_unordered(engine: RayEngine, work: Callable, shared, items: Iterable) -> Iterator[Landed]:
    """Each item as a task, `concurrency(engine)` at a time, yielded as it lands. Leaving
    early (an interrupt, or the caller stops) cancels the running tasks."""
    ray = _ray()
    owned = _connect(engine)
    running: dict = {}  # ObjectRef -> item
    try:
        n = concurrency(engine)
        remote = ray.remote(_task).options(
            num_cpus=engine.task_cpus,
            num_gpus=engine.task_gpus,
            max_retries=engine.max_retries,
            retry_exceptions=False,
            runtime_env={"env_vars": _env(engine)},
        )
        shared_ref = ray.put(shared)
        queue = iter(items)
        for item in queue:
            running[remote.remote(work, shared_ref, item)] = item
            if len(running) >= n:
                break
        while running:
            ready, _ = ray.wait(list(running), num_returns=1, timeout=_WAIT_S)
            for ref in ready:
                item = running.pop(ref)
                try:
                    value, worker, seconds, first = ray.get(ref)
                    landed = Landed(item, value, None, worker, seconds, first)
                except ray.exceptions.RayError as e:
                    landed = Landed(item, None, _failure(e))
                nxt = next(queue, _END)
                if nxt is not _END:
                    running[remote.remote(work, shared_ref, nxt)] = nxt
                yield landed
    finally:
        if owned:
            # Disconnecting ends this run's job, and Ray stops the job's running tasks.
            # (ray.cancel here can race with a task's completion and crash the driver
            # inside Ray: "Tried to complete task that was not pending".)
            ray.shutdown()
        else:  # (the caller's Ray session goes on: its tasks of this run are cancelled)
            _cancel(ray, list(running))


def _cancel(ray, refs: list) -> None:
    """Cancel the tasks of refs still running, best effort (a task finishing at the same
    moment may run to its end; its result is dropped)."""
    if not refs:
        return
    _, pending = ray.wait(refs, num_returns=len(refs), timeout=0)
    for ref in pending:
        try:
            ray.cancel(ref)
        except Exception:  # noqa: BLE001 - best effort on the way out
            pass


_END = object()
