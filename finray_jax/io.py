"""Finger files (TOML) and results (JSON).

This module sits on the public API: it reads a finger file into a `Finger` plus the
numerical settings of the solve, writes a finger back to TOML, and turns a `Solution`
into plain JSON-able data. The physics core never imports it.

Format reference: docs/finger-format.md. Units: mm, N, MPa; points are (x, z).

The work is done in one module per concern, gathered here:

- `_toml_reader`: typed reading of a TOML document, with messages that name the file,
  the key path and the value (`FingerFileError`);
- `_solve_settings`: `SolveSettings` and `GraspSettings`, read from [solver] and [grasp];
- `_finger_file`: a finger file (or a packaged one) into a `Finger` and its settings;
- `_finger_toml`: a `Finger` and its settings back to a finger file;
- `_solution_json`: solutions and limit loads as JSON;
- `_study_file`, `_run_files`: study files that name a base finger file, and the files
  their resumable runs keep.
"""

from ._finger_file import LOAD_KINDS as LOAD_KINDS
from ._finger_file import PACKAGED_FINGERS as PACKAGED_FINGERS
from ._finger_file import load_finger as load_finger
from ._finger_file import load_packaged_finger as load_packaged_finger
from ._finger_file import loads_finger as loads_finger
from ._finger_file import packaged_finger_text as packaged_finger_text
from ._finger_file import toml_paths as toml_paths
from ._finger_toml import finger_to_toml as finger_to_toml
from ._run_files import read_run_record as read_run_record
from ._run_files import write_atomic as write_atomic
from ._solution_json import UNITS as UNITS
from ._solution_json import json_text as json_text
from ._solution_json import limit_to_dict as limit_to_dict
from ._solution_json import solution_to_dict as solution_to_dict
from ._solution_json import to_plain as to_plain
from ._solution_json import write_json as write_json
from ._solve_settings import INTEGRATORS as INTEGRATORS
from ._solve_settings import MAX_ITERATIONS as MAX_ITERATIONS
from ._solve_settings import MAX_STEPS as MAX_STEPS
from ._solve_settings import MODES as MODES
from ._solve_settings import GraspSettings as GraspSettings
from ._solve_settings import SolveSettings as SolveSettings
from ._study_file import base_finger as base_finger
from ._study_file import load_study as load_study
from ._study_file import loads_study as loads_study
from ._toml_reader import FingerFileError as FingerFileError
from ._toml_reader import require_keys as require_keys

__all__ = [
    "FingerFileError",
    "SolveSettings",
    "load_finger",
    "loads_finger",
    "finger_to_toml",
    "solution_to_dict",
    "limit_to_dict",
    "write_json",
    "INTEGRATORS",
    "UNITS",
]
