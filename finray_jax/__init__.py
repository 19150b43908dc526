"""finray_jax: a differentiable Cosserat-rod simulator for fin-ray-effect grippers."""

import os as _os

import jax as _jax

if _os.environ.get("FINRAY_NO_AUTO_X64", "0") != "1":
    _jax.config.update("jax_enable_x64", True)

from ._bases import AbstractBase as AbstractBase
from ._bases import ClampedBase as ClampedBase
from ._bases import FreeBase as FreeBase
from ._bases import PinnedBase as PinnedBase
from ._cache import enable_compilation_cache as enable_compilation_cache
from ._cantilever import CantileverSolution as CantileverSolution
from ._cantilever import solve_cantilever as solve_cantilever
from ._contact import Contact as Contact
from ._contact import with_friction as with_friction
from ._contact_result import ContactResult as ContactResult
from ._contact_result import contact_result as contact_result
from ._errors import FingerError as FingerError
from ._errors import FingerWarning as FingerWarning
from ._finger import Adaptor as Adaptor
from ._finger import Crossbeams as Crossbeams
from ._finger import DistributedLoad as DistributedLoad
from ._finger import Finger as Finger
from ._finger import Material as Material
from ._finger import PointLoad as PointLoad
from ._finger import Section as Section
from ._finger import validate_finger as validate_finger
from ._fold import Fold as Fold
from ._fold import FoldOptions as FoldOptions
from ._fold import fold_point as fold_point
from ._fold import limit_load_factor as limit_load_factor
from ._geometry import AbstractTorsion as AbstractTorsion
from ._geometry import PaperTorsion as PaperTorsion
from ._geometry import SaintVenantTorsion as SaintVenantTorsion
from ._grasp import grasp as grasp
from ._grasp import regrasp as regrasp
from ._grasp_solution import GraspSolution as GraspSolution
from ._grasp_solution import stability as stability
from ._integrator import AbstractBackend as AbstractBackend
from ._integrator import DiffeqsolveBackend as DiffeqsolveBackend
from ._integrator import Integrator as Integrator
from ._integrator import StepBackend as StepBackend
from ._integrator import TableauBackend as TableauBackend
from ._objects import AbstractObject as AbstractObject
from ._objects import Circle as Circle
from ._objects import Ellipse as Ellipse
from ._objects import HalfPlane as HalfPlane
from ._objects import Polygon as Polygon
from ._objects import RoundedRectangle as RoundedRectangle
from ._options import AbstractLinearSolver as AbstractLinearSolver
from ._options import BandedLinearSolver as BandedLinearSolver
from ._options import DenseLinearSolver as DenseLinearSolver
from ._planar_rod import PlanarRod as PlanarRod
from ._reference import ref_finger_a as ref_finger_a
from ._release import ReleaseTrace as ReleaseTrace
from ._release import release_force as release_force
from ._rigid import RigidEstimate as RigidEstimate
from ._rigid import rigid_contact_estimate as rigid_contact_estimate
from ._solution import RESULTS as RESULTS
from ._solution import BeamSolution as BeamSolution
from ._solution import Solution as Solution
from ._solve import LimitLoad as LimitLoad
from ._solve import SolverOptions as SolverOptions
from ._solve import limit_load as limit_load
from ._solve import solve_finger as solve_finger
from ._solve import topology_of as topology_of
from ._spatial_rod import SpatialRod as SpatialRod
from ._stability import CriticalPoint as CriticalPoint
from ._stability import Stability as Stability
from ._version import __version__ as __version__
from .batch import BatchResult as BatchResult
from .batch import solve_batch as solve_batch
from .design import get_design as get_design
from .design import set_design as set_design
from .resolution import ResolutionCheck as ResolutionCheck
from .resolution import check_grasp_resolution as check_grasp_resolution
from .resolution import check_resolution as check_resolution
