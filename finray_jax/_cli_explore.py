"""`finray explore`: the design explorer in the browser (the `explore` extra: Bokeh).

The explorer's modules import Bokeh; they are loaded here, by name, only when the command
runs, so that the rest of the command line (and the library) never needs it."""

import importlib
import importlib.util

from . import io as fio
from ._cli_common import EXIT_OK, UserError, progress
from ._cli_finger import check_grasp_objects

DEFAULT_FINGER = "grasp_finger1_modified.toml"  # Finger-1, modified adaptor, 18 mm cylinder
INSTALL_HINT = "finray explore needs Bokeh: pip install 'finray_jax[explore]'"


def explore_command(args) -> int:
    if importlib.util.find_spec("bokeh") is None:
        raise UserError(INSTALL_HINT)
    if args.finger is None:
        finger, settings = fio.load_packaged_finger(DEFAULT_FINGER)
        source = f"{DEFAULT_FINGER} (packaged)"
    else:
        finger, settings = fio.load_finger(args.finger)
        check_grasp_objects(args.finger, finger, settings)
        source = args.finger
    if settings.grasp is not None and len(finger.objects) > 1:
        raise UserError(
            f"{source}: the explorer grasps one object; this file has {len(finger.objects)}"
        )
    app_module = importlib.import_module("finray_jax._explore_app")
    server = importlib.import_module("finray_jax._explore_server")
    app = app_module.App(finger, settings.grasp, source)
    progress(
        "preparing the explorer: the first design's solver and gradients compile (a minute "
        "or two the first time, cached afterwards); the page shows it meanwhile"
    )
    server.serve(app, port=args.port, open_browser=not args.no_browser)
    return EXIT_OK
