"""Record the solver's answers, or compare them with a recording: the check that a
restructuring of the solver changes no number.

    python benchmarks/same_answers.py record OUT.json   # on the reference commit
    python benchmarks/same_answers.py compare OUT.json  # on the commit under test

It solves ref-A's load cases planar and 3-D (roots, iterations, limit loads), every
shipped example, and Finger-1's grasps (original and modified adaptor, 6 mm) with a
release trace of the original. `compare` reports the largest relative difference of
every root and says where an iteration count differs; it exits 1 when a root differs by
more than 1e-10 relative (of its largest entry) or a count differs.
"""

import json
import pathlib
import sys

import numpy as np

import finray_jax as fr
from finray_jax.io import FingerFileError, load_finger

ROOT = pathlib.Path(__file__).resolve().parents[1]
RTOL = 1e-10


def _solution(sol):
    return {
        "unknowns": np.asarray(sol.unknowns).ravel().tolist(),
        "iterations": int(sol.iterations),
        "load_factor": float(sol.load_factor),
        "status": sol.status,
    }


def record():
    out = {}
    for mode in ("planar", "spatial"):
        for case in ("L1", "L2", "L3"):
            finger = fr.ref_finger_a(case)
            out[f"ref_a/{case}/{mode}"] = _solution(fr.solve_finger(finger, mode=mode))
        lim = fr.limit_load(fr.ref_finger_a("L2"), mode=mode)
        out[f"ref_a/L2/{mode}/limit"] = {"load_factor": float(lim.load_factor)}
    for path in sorted((ROOT / "examples").glob("*.toml")):
        try:
            finger, settings = load_finger(path)
        except FingerFileError:  # (sweep and optimisation files are not fingers)
            continue
        if finger.objects:
            continue
        out[f"example/{path.name}"] = _solution(fr.solve_finger(finger))
    for name in ("grasp_finger1.toml", "grasp_finger1_modified.toml"):
        finger, _ = load_finger(ROOT / "examples" / name)
        g = fr.grasp(finger, closing=6.0)
        item = _solution(g.solution)
        item["normal_force"] = float(g.contact.normal_force)
        item["stiffness"] = float(g.stiffness)
        out[f"grasp/{name}"] = item
        if name == "grasp_finger1.toml":
            trace = fr.release_force(g, friction=0.5)
            out[f"release/{name}"] = {
                "unknowns": np.asarray(trace.force).tolist(),
                "iterations": len(trace.force),
            }
        print(f"{name}: done", flush=True)
    return out


def compare(old, new):
    bad = []
    for key, a in old.items():
        b = new.get(key)
        if b is None:
            bad.append(f"{key}: missing")
            continue
        for field in ("unknowns", "load_factor", "normal_force", "stiffness"):
            if field not in a:
                continue
            x, y = np.atleast_1d(a[field]), np.atleast_1d(b[field])
            if x.shape != y.shape:
                bad.append(f"{key}.{field}: shape {x.shape} != {y.shape}")
                continue
            rel = float(np.max(np.abs(x - y)) / max(np.max(np.abs(x)), 1e-300))
            flag = "" if rel <= RTOL else "  <-- differs"
            print(f"{key:50s} {field:12s} {rel:9.2e}{flag}")
            if flag:
                bad.append(f"{key}.{field}: {rel:.2e}")
        if a.get("iterations") != b.get("iterations"):
            bad.append(f"{key}: iterations {a.get('iterations')} -> {b.get('iterations')}")
    return bad


def main(argv):
    if len(argv) != 2 or argv[0] not in ("record", "compare"):
        print(__doc__)
        return 2
    path = pathlib.Path(argv[1])
    if argv[0] == "record":
        path.write_text(json.dumps(record()))
        print(f"wrote {path}")
        return 0
    bad = compare(json.loads(path.read_text()), record())
    print("\n".join(bad) if bad else "same answers")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
