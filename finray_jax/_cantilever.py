"""A single clamped rod with an end load: the building block checked against closed forms."""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ._abstract_rod import TAPER_NODES
from ._finger import Material, Section
from ._flow import segment_flow, segment_trajectories
from ._geometry import AbstractTorsion, PaperTorsion, as_torsion, section_stiffness
from ._integrator import Integrator
from ._planar_rod import PlanarRod
from ._rod import rod_model
from ._segment_table import SegmentTable
from ._types import as_float, check_x64


class CantileverSolution(eqx.Module):
    s: jax.Array  # (segments * (steps + 1),)
    position: jax.Array  # (N, 3)
    frame: jax.Array  # (N, 3, 3)
    force: jax.Array
    moment: jax.Array
    result: optx.RESULTS
    max_residual: jax.Array


@eqx.filter_jit
def _solve(model, integrator, Q, tip_force, tip_moment):
    """Clamp at the origin along +z; end wrench given in the world frame."""
    segments = Q.shape[0]
    if isinstance(model, PlanarRod):
        y0 = model.full_from_unknown(jnp.zeros(6), 0.0)
        unknown = jnp.zeros(3)  # (nx, nz, my) at the base

        def start(u):
            return y0.at[3:6].set(u)

        def tip_rows(y):
            return jnp.stack([y[3] - tip_force[0], y[4] - tip_force[2], y[5] - tip_moment[1]])
    else:
        unknown = jnp.zeros(6)

        def start(u):
            return jnp.concatenate([jnp.zeros(3), jnp.eye(3).reshape(9), u])

        def tip_rows(y):
            return jnp.concatenate([y[12:15] - tip_force, y[15:18] - tip_moment])

    def chain(u):
        y = start(u)
        ys = []
        for k in range(segments):
            ys.append(y)
            y = segment_flow(model, integrator, y[None], Q[k][None])[0]
        return y, jnp.stack(ys)

    def fn(u, _):
        return tip_rows(chain(u)[0])

    sol = optx.root_find(
        fn, optx.Newton(rtol=1e-13, atol=1e-13), unknown, None, max_steps=60, throw=False
    )
    _, starts = chain(sol.value)
    traj = segment_trajectories(model, integrator, starts, Q)
    return traj, sol.result, jnp.max(jnp.abs(fn(sol.value, None)))


def solve_cantilever(
    length,
    material: Material,
    section: Section,
    *,
    tip_force=(0.0, 0.0, 0.0),
    tip_moment=(0.0, 0.0, 0.0),
    mode: str = "planar",
    segments: int = 4,
    integrator: Integrator = Integrator(),
    torsion: AbstractTorsion = PaperTorsion(),
) -> CantileverSolution:
    """A rod clamped at the origin along +z, loaded at its free end by a dead force (N) and
    moment (N mm) in the world frame, solved by shooting on the base wrench.

    The rod is cut into `segments` equal segments, each integrated at integrator.steps
    fixed steps, so the total number of steps is segments * steps. A section with
    tip_thickness tapers linearly from the clamp to the free end.
    """
    check_x64("solve_cantilever")
    torsion = as_torsion(torsion, "torsion")
    length = as_float(length)
    if not float(length) > 0:
        raise ValueError(f"length must be positive, got {float(length)}")
    if mode not in ("planar", "spatial"):
        raise ValueError(f"mode must be 'planar' or 'spatial', got {mode!r}")
    model = rod_model(mode, section.tip_thickness is not None)
    L = length / segments
    start_s = jnp.arange(segments, dtype=L.dtype) * L
    nodes = start_s[:, None] + jnp.asarray(TAPER_NODES)[None] * L
    t = section.thickness * jnp.ones_like(nodes)
    if section.tip_thickness is not None:
        t = t + (section.tip_thickness - section.thickness) * nodes / length
    z3 = jnp.zeros((segments, 3))
    table = SegmentTable(
        start_s=start_s,
        length=jnp.full(segments, L),
        rigid=jnp.zeros(segments),
        contact=jnp.zeros((segments, 0)),
        stiffness=section_stiffness(material, t, section.depth, torsion),
        force=z3,
        precurvature=z3,
        theta=jnp.zeros(segments),
        point=z3,
    )
    traj, result, res = _solve(
        model, integrator, model.pack(table), as_float(tip_force), as_float(tip_moment)
    )
    steps = integrator.steps
    s = start_s[:, None] + jnp.linspace(0.0, 1.0, steps + 1)[None] * L
    st = traj.reshape(-1, traj.shape[-1])
    return CantileverSolution(
        s=s.reshape(-1),
        position=jax.vmap(model.position)(st),
        frame=jax.vmap(model.frame)(st),
        force=jax.vmap(model.force)(st),
        moment=jax.vmap(model.moment)(st),
        result=result,
        max_residual=res,
    )
