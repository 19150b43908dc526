"""Files of resumable runs (sweeps, optimisations): atomic writes, and the JSON record
that ties an output directory to the run that wrote it."""

from __future__ import annotations

import json
import os


def write_atomic(path, text: str) -> None:
    """Write a file through a flushed and fsync'ed temporary and a rename, so that an
    interruption leaves the old file or the new one, never a torn one."""
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_run_record(path, out_dir, error, *, what, run, digest, hash_key, source_key) -> dict:
    """The JSON record a resumable run keeps in its output directory (a sweep's manifest,
    an optimisation's checkpoint), checked to belong to this `run` (same hash)."""
    try:
        with open(path, encoding="utf-8") as fh:
            record = json.load(fh)
    except (OSError, ValueError) as e:
        raise error(
            f"{path}: unreadable {what} ({e}); remove {out_dir} or use another --out"
        ) from None
    if record.get(hash_key) != digest:
        raise error(
            f"{out_dir} holds another {run} (from {record.get(source_key, '?')}, hash "
            f"{str(record.get(hash_key))[:12]}; this one's hash is {digest[:12]}; the hash "
            f"covers the {run} file and its finger file, so one of them differs): use another "
            "--out directory, or delete that one to start again"
        )
    return record
