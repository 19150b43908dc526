"""Static Cosserat rods: two models of the same physics, picked by name.

`PlanarRod` (`_planar_rod`) keeps (x, z, theta, nx, nz, my); `SpatialRod` (`_spatial_rod`)
keeps (p, R, n, m). Both implement `AbstractRodModel` (`_abstract_rod`); `_flow`
integrates any of them over every segment.
"""

from ._abstract_rod import AbstractRodModel
from ._planar_rod import PlanarRod
from ._spatial_rod import SpatialRod


def rod_model(mode: str, tapered: bool = False, contact=None) -> AbstractRodModel:
    """The model for `mode` ("planar" or "spatial"), with a tapered section's stiffness
    samples if `tapered` and the contact layout `contact` (a `ContactSpec` or None)."""
    return {"planar": PlanarRod, "spatial": SpatialRod}[mode](tapered=tapered, contact=contact)
