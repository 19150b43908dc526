"""Grasp results as JSON documents: plain dicts of lists, floats, strings, booleans and
None, the data `finray grasp --out` and `finray compare` write.

Arrays become (nested) lists of floats. A value that is unknown stays a NaN float here;
`finray_jax.io.write_json` writes it as null. Units are the package's: mm, N, MPa
(penalty stiffnesses in N/mm^2, pressures in N/mm).
"""

import numpy as np

# The fields of a `RigidEstimate` its document holds, in the document's order.
_RIGID_ESTIMATE_FIELDS = (
    "factors",
    "stiffness",
    "support_stiffness",
    "values",
    "order",
    "rigid",
    "distance",
)


def stability_to_dict(g) -> dict | None:
    """The stability of a grasp's equilibrium (`GraspSolution.stability`) and the critical
    points of its closing path; None when the grasp has no stability analysis.

    Keys: stable, min_eigenvalue and eigenvalues (the smallest few of the condensed
    tangent stiffness, ascending), conjugate_segments, critical_points (one sentence each).
    """
    s = g.stability
    if s is None:
        return None
    return {
        "stable": s.stable,
        "min_eigenvalue": s.min_eigenvalue,
        "eigenvalues": s.eigenvalues.tolist(),
        "conjugate_segments": list(s.conjugate_segments),
        "critical_points": [c.describe() for c in g.critical_points],
    }


def release_to_dict(trace) -> dict:
    """A release trace (`ReleaseTrace`): the holding force (peak, N) and the pull at which
    it peaks (peak_pull, mm), whether the trace reached the loss of contact (complete), its
    message, and the force (N) at each pull distance (mm)."""
    return {
        "peak": trace.peak,
        "peak_pull": trace.peak_pull,
        "complete": trace.complete,
        "message": trace.message,
        "pull": trace.pull.tolist(),
        "force": trace.force.tolist(),
    }


def _beam_pressure(beam, q) -> dict:
    return {"s": np.asarray(beam.s).tolist(), "q": np.asarray(q).tolist()}


def _wrench(r) -> dict:
    return {"force": np.asarray(r.force).tolist(), "moment": np.asarray(r.moment).tolist()}


def grasp_to_dict(g, release=None) -> dict:
    """A grasp (`GraspSolution`) as a JSON document, with its release trace when given.

    Keys: status, closing (mm), the objects' and the support's penalty stiffnesses, the
    Newton residual, stability (`stability_to_dict`), contact (`ContactResult`: the total
    force the objects exert on the finger, normal force, contact length, penetrations,
    support force, mean crossbeam force on the front beam, actuator force, and the
    normal pressure q(s) at each beam's solution points s),
    reactions (the wrench the adaptor applies at each beam's base), and release
    (`release_to_dict`) when `release` is given.
    """
    c = g.contact
    out = {
        "status": g.status,
        "closing": float(g.closing),
        "penalty_stiffness": float(g.stiffness),
        "support_penalty_stiffness": float(g.support_stiffness),
        "max_residual": float(g.solution.max_residual),
        "stability": stability_to_dict(g),
        "contact": {
            "force": np.asarray(c.force).tolist(),
            "normal_force": float(c.normal_force),
            "contact_length": float(c.contact_length),
            "max_penetration": float(c.max_penetration),
            "support_force": np.asarray(c.support_force).tolist(),
            "support_penetration": float(c.support_penetration),
            "crossbeam_force_mean": np.asarray(c.crossbeam_force).tolist(),
            "actuator_force": float(c.actuator_force),
            "pressure_front": _beam_pressure(g.solution.front, c.pressure_front),
            "pressure_back": _beam_pressure(g.solution.back, c.pressure_back),
        },
        "reactions": {
            "front": _wrench(g.solution.reactions_front),
            "back": _wrench(g.solution.reactions_back),
        },
    }
    if release is not None:
        out["release"] = release_to_dict(release)
    return out


def rigid_estimate_to_dict(rigid) -> dict:
    """A rigid-contact estimate (`RigidEstimate`): the stiffness factors, the penalty
    stiffnesses at each, and per output its values, observed order, extrapolated rigid
    value and the grasp's relative distance from it (NaN order: no power-law convergence
    observed, the distance is a lower bound)."""
    return {key: getattr(rigid, key) for key in _RIGID_ESTIMATE_FIELDS}


def comparison_to_dict(cmp) -> dict:
    """An adaptor comparison (`studies.Comparison`): the closing (mm), the grasp of each
    adaptor (`grasp_to_dict`) and the contact force gain (percent), the same with the
    object placed above the support's end (None when not solved), and per release
    diameter (mm, as a string key) the holding force of each adaptor and its gain."""
    return {
        "closing": cmp.closing,
        "original": grasp_to_dict(cmp.original),
        "modified": grasp_to_dict(cmp.modified),
        "contact_force_gain_percent": cmp.contact_force_gain,
        "placed": None
        if cmp.placed is None
        else {
            "height": cmp.placed[0],
            "original": grasp_to_dict(cmp.placed[1]),
            "modified": grasp_to_dict(cmp.placed[2]),
            "contact_force_gain_percent": cmp.placed_gain,
        },
        "release": {
            str(d): {
                "original": a.peak,
                "modified": b.peak,
                "gain_percent": cmp.release_gain(d),
            }
            for d, (a, b) in cmp.release.items()
        },
    }
