"""The data of a batch of designs: the design values going in (checked, padded to a
chunk) and the per-design results coming out (`BatchResult`, its status names, and
`Diagnosis`: why a design was not solved)."""

from __future__ import annotations

import functools
from collections.abc import Mapping

import equinox as eqx
import jax
import numpy as np

from ._cuts import build_topology, event_s
from ._finger import Finger, FingerError, beam_name, validate_finger
from ._solution import RESULTS
from .design import DesignError, check_design_names, get_design, set_design

#: Result code of a design that was not solved (invalid, or outside the base topology).
INVALID = -1


def one_line(text) -> str:
    """text on one line (its whitespace runs made single spaces), for a CSV cell or a log."""
    return " ".join(str(text).split())


def _event_name(kind: str, index: int) -> str:
    return {
        "cb": f"crossbeam {index}",
        "point": f"loads[{index}]",
        "dist_start": f"the start of loads[{index}]",
        "dist_end": f"the end of loads[{index}]",
    }.get(kind, "the support's end (adaptor.support_length)")


_designed = eqx.filter_jit(set_design)  # (one compile per set of names, not per design)


class Diagnosis:
    """Why a design of a batch was not solved (status "invalid"), as one line: the finger
    validation's message (`validate_finger`: the field and its value), else the change of
    the base finger's topology (which event now comes before which, where). Called with
    one design's values (name -> value); eager, on the host."""

    def __init__(self, base: Finger, mode: str, topology=None):
        self.base, self.mode, self._topology = base, mode, topology

    @functools.cached_property
    def base_events(self):
        topo = self._topology
        return (build_topology(self.base, self.mode) if topo is None else topo).events

    def __call__(self, values: Mapping[str, object]) -> str:
        vals = {k: np.asarray(v, dtype=np.float64) for k, v in values.items()}
        try:
            finger = jax.device_get(_designed(self.base, vals))
            validate_finger(finger)
            moved = self._topology_change(finger)
        except FingerError as e:
            return one_line(e)
        except Exception as e:  # noqa: BLE001 - a reason, whatever went wrong
            return one_line(f"invalid design ({type(e).__name__}: {e})")
        if moved is not None:
            return moved
        return (
            "invalid design: a value is out of range or it changes the base finger's topology "
            "(the order of crossbeams, load points and the support's end along a beam)"
        )

    def _topology_change(self, finger: Finger) -> str | None:
        events = build_topology(finger, self.mode).events
        for beam, (old, new) in enumerate(zip(self.base_events, events)):
            old = [e for e in old if e[0] != "sub"]
            new = [e for e in new if e[0] != "sub"]
            for a, c in zip(old, new):
                if a != c:
                    where = {0: "the front beam", 1: "the back beam"}.get(beam, beam_name(beam))
                    sa, sc = (float(np.asarray(event_s(finger, beam, *e))) for e in (a, c))
                    return (
                        "changes the base finger's topology (the order of events along a "
                        f"beam): on {where}, {_event_name(*c)} at s = {sc:.6g} now comes "
                        f"before {_event_name(*a)} at s = {sa:.6g}"
                    )
        return None


class BatchResult(eqx.Module):
    """Per-design results of a batch (host numpy arrays, B designs).

    inputs, outputs: name -> (B,) (or (B, C) for a whole crossbeam array) values. Outputs
        are NaN for invalid and failed designs; beyond the limit load they are those of
        the equilibrium at the fold (see the "load_factor" output).
    result: RESULTS codes (int), INVALID (-1) for designs that were not solved.
    iterations: Newton iterations; max_residual: largest scaled residual (NaN if invalid).
    diagnosis: what `message` asks why a design is invalid (set by `solve_batch`).
    """

    inputs: dict[str, np.ndarray]
    outputs: dict[str, np.ndarray]
    result: np.ndarray
    iterations: np.ndarray
    max_residual: np.ndarray
    diagnosis: Diagnosis | None = eqx.field(default=None, static=True)

    @property
    def size(self) -> int:
        return int(self.result.shape[0])

    @property
    def status(self) -> np.ndarray:
        """'converged' | 'beyond_limit_load' | 'failed' | 'invalid' per design."""
        return status_names(self.result)

    def message(self, i: int) -> str:
        """What the result of design i means (and what to do)."""
        code = int(self.result[i])
        if code == INVALID:
            if self.diagnosis is not None:
                return self.diagnosis({k: v[i] for k, v in self.inputs.items()})
            return (
                "invalid design: a value is not finite or out of range (thickness, depth or E "
                "not positive, attachment outside its beam), or it changes the base finger's "
                "topology (order of attachments and load points along a beam)"
            )
        return RESULTS._index_to_message[code] or "converged"


def status_names(result) -> np.ndarray:
    """Status names of RESULTS codes (INVALID -> 'invalid')."""
    code = np.asarray(result)
    names = np.full(code.shape, "failed", dtype=object)
    names[code == int(RESULTS.successful._value)] = "converged"
    names[code == int(RESULTS.beyond_limit_load._value)] = "beyond_limit_load"
    names[code == INVALID] = "invalid"
    return names


def check_values(base: Finger, values: Mapping) -> tuple[dict[str, np.ndarray], int]:
    """The design values of a batch as float64 arrays, one row per design, and the number
    of designs; a DesignError names a value of the wrong name, shape or length."""
    if not isinstance(values, Mapping) or not values:
        raise DesignError("values must be a non-empty dict: design-value name -> (B,) array")
    check_design_names(base, values)
    shapes = {k: np.shape(v) for k, v in get_design(base, list(values)).items()}
    arrays, size = {}, None
    for name, v in values.items():
        a = np.asarray(v, dtype=np.float64)
        if a.ndim != 1 + len(shapes[name]) or a.shape[1:] != shapes[name]:
            raise DesignError(
                f"values[{name!r}] must have shape (B,) + {shapes[name]} (one row per design), "
                f"got {a.shape}"
            )
        if size is not None and a.shape[0] != size:
            raise DesignError(
                f"values[{name!r}] has {a.shape[0]} designs, the others {size}: all value arrays "
                "need the same length"
            )
        arrays[name], size = a, a.shape[0]
    return arrays, size


def pad(arrays, rows: slice | np.ndarray, size: int, fill) -> dict[str, np.ndarray]:
    """The rows of every value array, padded to `size` rows with `fill` (name -> value)."""
    out = {}
    for name, v in arrays.items():
        part = v[rows]
        padding = np.broadcast_to(fill[name], (size - part.shape[0],) + v.shape[1:])
        out[name] = np.concatenate([part, padding])
    return out


def chunk_result(arrays, rows: slice, outs, code, its, res, diagnosis) -> BatchResult:
    """The BatchResult of a chunk: its rows of the value arrays beside what was solved."""
    inputs = {k: v[rows] for k, v in arrays.items()}
    return BatchResult(inputs, outs, code, its, res, diagnosis)
