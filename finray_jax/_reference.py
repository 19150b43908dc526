"""The reference finger ref-A and its load cases, defined here (the same finger under L1
as a finger file: examples/ref_a.toml)."""

import numpy as np

from ._bases import ClampedBase
from ._finger import Adaptor, Crossbeams, DistributedLoad, Finger, Material, PointLoad, Section

REF_A_LOADS = ("none", "L1", "L2", "L3")


def ref_finger_a(load: str = "L1", *, shear_coefficient: float = 5.0 / 6.0) -> Finger:
    """ref-A: 120 mm front beam, back base at (40, 0), 7 horizontal crossbeams.

    load: "none", "L1" (0.05 N at s = 60), "L2" (1.5 N at s = 60) or "L3" (1 N uniform
    over s in [75, 105]), all in +x on the front beam.
    """
    z = 15.0 * np.arange(1, 8)
    lb = float(np.hypot(40.0, 120.0))
    n = len(z)
    loads = {
        "none": (),
        "L1": (PointLoad(0, 60.0, (0.05, 0.0, 0.0)),),
        "L2": (PointLoad(0, 60.0, (1.5, 0.0, 0.0)),),
        "L3": (DistributedLoad(0, (75.0, 105.0), (1.0, 0.0, 0.0)),),
    }
    if load not in loads:
        raise ValueError(f"load must be one of {REF_A_LOADS}, got {load!r}")
    return Finger(
        material=Material(E=12.0, nu=0.45, shear_coefficient=shear_coefficient),
        front_base=(0.0, 0.0),
        back_base=(40.0, 0.0),
        tip=(0.0, 120.0),
        front=Section(1.5, 20.0),
        back=Section(1.5, 20.0),
        crossbeams=Crossbeams(z, z * lb / 120.0, np.full(n, 1.0), np.full(n, 20.0)),
        adaptor=Adaptor(ClampedBase(), ClampedBase()),
        loads=loads[load],
    )
