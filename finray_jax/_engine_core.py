"""What every engine shares: its error, the outcome of one item (`Landed`), running an
item timed in this process, and `LocalEngine`, which runs them all here. Ray is never
imported here (`require_ray` imports it when asked)."""

from __future__ import annotations

import dataclasses
import os
import socket
import time
from collections.abc import Callable, Iterable, Iterator

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


def require_ray() -> None:
    """Import Ray, or raise an EngineError that says how to install it."""
    try:
        import ray  # noqa: F401
    except ImportError:
        raise EngineError(
            f"the ray engine needs Ray, which is not installed here: {RAY_HINT}"
        ) from None
