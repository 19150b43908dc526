"""`RayEngine`'s mechanics: connect to (or start) a Ray cluster, run each item as a Ray
Core task, keep `workers` of them running, and yield each as it lands. Imported only when
a RayEngine runs (it imports ray)."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Iterator

from ._cache import enable_compilation_cache
from .engines import EngineError, Landed, RayEngine, require_ray, run_item

require_ray()  # (a clear line instead of the import's traceback)
import ray  # noqa: E402
import ray.exceptions  # noqa: E402

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
    have = ray.cluster_resources()
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


def map_unordered(engine: RayEngine, work: Callable, shared, items: Iterable) -> Iterator[Landed]:
    """Each item as a task, `concurrency(engine)` at a time, yielded as it lands. Leaving
    early (an interrupt, or the caller stops) cancels the running tasks."""
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
        for ref in running:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
        if owned:
            ray.shutdown()


_END = object()
