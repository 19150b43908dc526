"""JAX's persistent compilation cache, shared by the CLI and any script that asks for it."""

import os


def enable_compilation_cache() -> str | None:
    """Turn on JAX's persistent compilation cache, so that a later process solving a
    finger of the same topology loads the compiled programs instead of compiling them
    (benchmarks/README.md gives a new process's first solve with the cache empty and
    filled).

    Every `finray` command (but validate) calls it; the library never does by itself.
    Call it at the top of a script or notebook to share the CLI's cache. Directory:
    $FINRAY_CACHE_DIR, else ~/.cache/finray_jax/jax. FINRAY_NO_CACHE=1 disables it.
    Returns the directory, or None when disabled.
    """
    if os.environ.get("FINRAY_NO_CACHE", "0").strip() not in ("", "0"):
        return None
    import jax

    path = os.environ.get("FINRAY_CACHE_DIR") or os.path.expanduser("~/.cache/finray_jax/jax")
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return path
