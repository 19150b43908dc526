"""Conventions used throughout finray_jax, written once.

Units
    millimetre, newton, megapascal (N/mm^2); moments in N mm.

Plane and axes
    The finger lies in the x-z plane; y is out of plane (the beams' depth). Points given by
    the user as pairs are (x, z). Internally every position is a 3-vector (x, y, z).

Arc length
    s runs from each beam's base (s = 0) to its tip; crossbeams run from their front-beam
    end (s = 0) to their back-beam end. Arc length is the ODE's time.

Frames
    A material frame R has columns d1, d2, d3 in world coordinates. d3 is the centreline
    tangent, d2 the depth direction (world +y for an in-plane finger), d1 = d2 x d3 the
    in-plane thickness direction. In the planar mode the frame is a rotation about +y by
    the angle theta: d3 = (sin theta, 0, cos theta), d1 = (cos theta, 0, -sin theta).

Internal wrench
    n(s), m(s) are the force and moment (about the centreline point p(s)) that the material
    at s+ exerts on the material at s-. A point force F at s makes n jump by -F.

Reactions
    The force and moment the adaptor applies to a beam at its base, the moment taken about
    the base point: (-n(0), -m(0)).
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

Scalar = Float[Array, ""]
Vector3 = Float[Array, "3"]
Point2 = Float[Array, "2"]


def check_x64(where: str) -> None:
    """Raise unless 64-bit floats are enabled: this problem needs float64."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            f"{where} needs float64. Enable it before using finray_jax, e.g. "
            "`jax.config.update('jax_enable_x64', True)` or the environment variable "
            "JAX_ENABLE_X64=1. (Importing finray_jax enables it unless "
            "FINRAY_NO_AUTO_X64=1 is set.)"
        )


def as_float(x) -> Array:
    return jnp.asarray(x, dtype=jnp.float64)
