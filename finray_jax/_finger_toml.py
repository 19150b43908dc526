"""Writing a `Finger` (and its `SolveSettings`) as a finger file (TOML).

Numbers are written exactly (repr round-trips), so `load_finger` reads back equal arrays.
One function per table, each returning its lines.
"""

from __future__ import annotations

import json
import math

import numpy as np

from ._finger import DistributedLoad, Finger, PointLoad, validate_finger
from ._finger_file import OBJECT_KEYS
from ._integrator import Integrator
from ._options import AbstractLinearSolver
from ._solve_settings import INTEGRATORS, GraspSettings, SolveSettings, solver_option_fields


def finger_to_toml(finger: Finger, settings: SolveSettings | None = None) -> str:
    """A finger (and optionally its solve settings, with its [grasp] table when they have
    one) as a finger file.

    Values are written exactly (`load_finger` gives back equal arrays). Crossbeams are
    always written as explicit [[crossbeams]] tables.
    """
    validate_finger(finger)
    out = [
        "# finray_jax finger file. Units: mm, N, MPa; points are (x, z).",
        f"torsion = {_ts(finger.torsion.name)}",
        "",
    ]
    if settings is not None:
        out += _meta_toml(settings)
    out += _material_toml(finger)
    out += _beams_toml(finger)
    out += _adaptor_toml(finger)
    out += _objects_toml(finger)
    out += _crossbeams_toml(finger)
    out += _loads_toml(finger)
    if settings is not None:
        out += _settings_toml(settings)
    if settings is not None and settings.grasp is not None:
        out += _grasp_toml(settings.grasp)
    return "\n".join(out).rstrip("\n") + "\n"


def _tf(x) -> str:
    """A float in TOML, exactly (repr round-trips)."""
    v = float(x)
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(v)


def _tv(xs) -> str:
    return "[" + ", ".join(_tf(x) for x in np.asarray(xs, dtype=np.float64).reshape(-1)) + "]"


def _ts(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def _meta_toml(settings: SolveSettings) -> list[str]:
    """[meta], when the settings carry a name or a description."""
    if not (settings.name or settings.description):
        return []
    out = ["[meta]"]
    if settings.name:
        out.append(f"name = {_ts(settings.name)}")
    if settings.description:
        out.append(f"description = {_ts(settings.description)}")
    return out + [""]


def _material_toml(finger: Finger) -> list[str]:
    m = finger.material
    return [
        "[material]",
        f"E = {_tf(m.E)}",
        f"nu = {_tf(m.nu)}",
        f"shear_coefficient = {_tf(m.shear_coefficient)}",
        "",
    ]


def _beams_toml(finger: Finger) -> list[str]:
    """[front] (with the shared tip) and [back]."""
    return [
        "[front]",
        f"base = {_tv(finger.front_base)}",
        f"tip = {_tv(finger.tip)}",
        f"thickness = {_tf(finger.front.thickness)}",
        f"depth = {_tf(finger.front.depth)}",
        *_optional_lines(finger.front, finger.front_curvature),
        "",
        "[back]",
        f"base = {_tv(finger.back_base)}",
        f"thickness = {_tf(finger.back.thickness)}",
        f"depth = {_tf(finger.back.depth)}",
        *_optional_lines(finger.back, finger.back_curvature),
        "",
    ]


def _optional_lines(section, curvature):
    out = []
    if section.tip_thickness is not None:
        out.append(f"tip_thickness = {_tf(section.tip_thickness)}")
    if float(curvature) != 0.0:
        out.append(f"curvature = {_tf(curvature)}")
    return out


def _adaptor_toml(finger: Finger) -> list[str]:
    ad = finger.adaptor
    return [
        "[adaptor]",
        f"front_base = {_ts(ad.front_base.name)}",
        f"back_base = {_ts(ad.back_base.name)}",
        f"front_clamp_length = {_tf(ad.front_clamp_length)}",
        f"back_clamp_length = {_tf(ad.back_clamp_length)}",
        *([] if ad.support_length is None else [f"support_length = {_tf(ad.support_length)}"]),
        "",
    ]


def _crossbeams_toml(finger: Finger) -> list[str]:
    """One [[crossbeams]] table per crossbeam, numbered in a comment."""
    cb = finger.crossbeams
    out = []
    for i in range(finger.n_crossbeams):
        out += [
            f"[[crossbeams]]  # {i}",
            f"front_s = {_tf(cb.front_s[i])}",
            f"back_s = {_tf(cb.back_s[i])}",
            f"thickness = {_tf(cb.thickness[i])}",
            f"depth = {_tf(cb.depth[i])}",
            "",
        ]
    return out


def _loads_toml(finger: Finger) -> list[str]:
    """One [[loads]] table per load; a beam written "front", "back" or a crossbeam index."""
    out = []
    for load in finger.loads:
        beam = {0: '"front"', 1: '"back"'}.get(load.beam, str(load.beam - 2))
        if isinstance(load, PointLoad):
            out += [
                "[[loads]]",
                'kind = "point"',
                f"beam = {beam}",
                f"s = {_tf(load.s)}",
                f"force = {_tv(load.force)}",
                f"moment = {_tv(load.moment)}",
                "",
            ]
        elif isinstance(load, DistributedLoad):
            out += [
                "[[loads]]",
                'kind = "distributed"',
                f"beam = {beam}",
                f"s_range = {_tv(load.s_range)}",
                f"total_force = {_tv(load.total_force)}",
                "",
            ]
        else:
            raise TypeError(f"cannot write a {type(load).__name__} to a finger file")
    return out


def _objects_toml(finger: Finger) -> list[str]:
    """[[objects]] and [contact]: written when the finger touches anything (objects, or
    a support below its base)."""
    if not (finger.objects or finger.adaptor.support_length is not None):
        return []
    out = []
    for obj in finger.objects:
        out += ["[[objects]]", f"kind = {_ts(obj.kind)}"]
        need, optional = OBJECT_KEYS[obj.kind]
        for key in need + optional:
            if key == "angle_deg":
                out.append(f"angle_deg = {_tf(np.rad2deg(float(obj.angle)))}")
            elif key == "vertices":
                out.append("vertices = [" + ", ".join(_tv(v) for v in obj.vertices) + "]")
            else:
                v = getattr(obj, key)
                out.append(f"{key} = {_tv(v) if np.ndim(v) else _tf(v)}")
        out.append("")
    return out + _contact_toml(finger)


def _contact_toml(finger: Finger) -> list[str]:
    """[contact]; the options left unset (None, a rule of their own) are left out."""
    c = finger.contact
    out = ["[contact]"]
    if c.stiffness is not None:
        out.append(f"stiffness = {_tf(c.stiffness)}")
    out.append(f"max_penetration = {_tf(c.max_penetration)}")
    if c.support_stiffness is not None:
        out.append(f"support_stiffness = {_tf(c.support_stiffness)}")
    if c.max_support_penetration is not None:
        out.append(f"max_support_penetration = {_tf(c.max_support_penetration)}")
    if c.member_contact is not None:
        out.append(f"member_contact = {'true' if c.member_contact else 'false'}")
    if c.member_stiffness is not None:
        out.append(f"member_stiffness = {_tf(c.member_stiffness)}")
    if c.max_member_penetration is not None:
        out.append(f"max_member_penetration = {_tf(c.max_member_penetration)}")
    out.append(f"member_reach = {_tf(c.member_reach)}")
    out += [
        f"friction = {_tf(c.friction)}",
        f"friction_regularisation = {_tf(c.friction_regularisation)}",
        f"segment_length = {_tf(c.segment_length)}",
        "near_segments = " + ('"all"' if c.near_segments is None else str(c.near_segments)),
        "",
    ]
    return out


def _settings_toml(settings: SolveSettings) -> list[str]:
    """[solver]: every option written, so that the file pins the solve."""
    integ = settings.integrator
    name = type(integ.solver).__name__
    if name not in INTEGRATORS:
        raise ValueError(
            f"cannot write integrator solver {name} to a finger file; use one of "
            f"{tuple(INTEGRATORS)}"
        )
    out = [
        "[solver]",
        f"mode = {_ts(settings.mode)}",
        f"integrator = {_ts(name)}",
        f"steps = {integ.steps}",
    ]
    if integ.backend != Integrator().backend:
        out.append(f"backend = {_ts(integ.backend.name)}")
    for f in solver_option_fields():
        v = getattr(settings.options, f.name)
        if v is None and f.name == "max_rotation_step":  # the cap switched off
            out.append(f"{f.name} = false")
            continue
        if v is None:  # an option left to its default rule (reuse_jacobian_below)
            continue
        if isinstance(f.default, bool):
            out.append(f"{f.name} = {'true' if v else 'false'}")
        elif isinstance(f.default, AbstractLinearSolver):
            out.append(f"{f.name} = {_ts(v.name)}")
        elif isinstance(f.default, int):
            out.append(f"{f.name} = {int(v)}")
        else:
            out.append(f"{f.name} = {_tf(v)}")
    return out + [""]


def _grasp_toml(gs: GraspSettings) -> list[str]:
    """[grasp]: how the finger closes on its objects (the keys that are set)."""
    out = ["[grasp]"]
    if gs.closing is not None:
        out.append(f"closing = {_tf(gs.closing)}")
    if gs.actuator_force is not None:
        out.append(f"actuator_force = {_tf(gs.actuator_force)}")
    out += [
        f"direction = {_tv(gs.direction)}",
        f"symmetric = {'true' if gs.symmetric else 'false'}",
        f"pull_step = {_tf(gs.pull_step)}",
        f"release = {'true' if gs.release else 'false'}",
    ]
    if gs.friction is not None:
        out.append(f"friction = {_tf(gs.friction)}")
    return out + [""]
