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

from ._engine_core import EngineError, Landed, LocalEngine, require_ray
from ._ray_engine import RayEngine

__all__ = ["EngineError", "Landed", "LocalEngine", "RayEngine", "engine_named", "require_ray"]


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
