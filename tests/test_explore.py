"""`finray explore`: the design explorer's page in a real browser (headless Chromium driven
by selenium), against the library's own answers.

One server (in this process, on a free port) and one browser serve every test of the
module; the page's models are read and set through BokehJS (`Bokeh.documents[0]`), which
drives the same server callbacks as a drag. The tests' own solves reuse the programs the
page compiled (the same segment tables, integrator and penalty stiffnesses), and the grasp
of a downloaded finger file, solved once, serves every test that downloads that file. A
screenshot of the page is saved under $FINRAY_TEST_ARTIFACTS (default tests/artifacts/).
Without bokeh, selenium or Chromium the browser tests are skipped, unless `--require
selenium` asks for them (`make test`).
"""

import asyncio
import base64
import dataclasses
import json
import math
import os
import pathlib
import shutil
import tempfile
import threading
import time

import numpy as np
import pytest

import finray_jax as fr
from finray_jax import io as fio

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODIFIED = ROOT / "examples" / "grasp_finger1_modified.toml"
ARTIFACTS = pathlib.Path(os.environ.get("FINRAY_TEST_ARTIFACTS") or ROOT / "tests" / "artifacts")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
)
READY_S = 900  # the first design's compiles (a few minutes on a loaded 2-core machine)
SOLVE_S = 300  # one change (a warm solve; a closing path where it falls back)
LIMIT_S = 900  # the closing path up to the actuator force's peak (two minutes loaded)


# --------------------------------------------------------------------------------------
# The server and the browser (one each for the module)
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def server():
    pytest.importorskip("bokeh")
    from finray_jax._explore_app import App
    from finray_jax._explore_server import address, start_server

    finger, settings = fio.load_finger(MODIFIED)
    app = App(finger, settings.grasp, str(MODIFIED), say=lambda m: None)
    box, started = {}, threading.Event()

    def run():
        asyncio.set_event_loop(asyncio.new_event_loop())
        box["server"] = start_server(app, port=0)
        started.set()
        box["server"].io_loop.start()

    threading.Thread(target=run, name="explore-test-server", daemon=True).start()
    assert started.wait(60), "the server did not start"
    app.prepare()
    yield app, address(box["server"])
    app.worker.wait_idle(LIMIT_S)  # (no solve left running when the process ends)
    srv = box["server"]
    srv.io_loop.add_callback(srv.stop)
    srv.io_loop.add_callback(srv.io_loop.stop)


def _browser_or_skip(request):
    required = "selenium" in request.config.getoption("--require")
    webdriver = pytest.importorskip("selenium.webdriver")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not (chromium and driver):
        message = (
            "needs Chromium and chromedriver (Debian: apt-get install chromium chromium-driver)"
        )
        if required:
            pytest.fail(message)
        pytest.skip(message)
    return webdriver, chromium, driver


@pytest.fixture(scope="module")
def page(request, server):
    webdriver, chromium, driver = _browser_or_skip(request)
    app, url = server
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    profile = tempfile.mkdtemp(prefix="finray-chromium-")
    for flag in CHROMIUM_FLAGS + (f"--user-data-dir={profile}",):
        opts.add_argument(flag)
    browser = webdriver.Chrome(
        service=webdriver.ChromeService(executable_path=driver), options=opts
    )
    browser.set_window_size(1500, 1500)
    browser.get(url)
    try:
        _wait(browser, lambda: app.ready and len(_column(browser, "numbers", "value")) > 0, READY_S)
        yield app, browser
    finally:
        browser.quit()
        shutil.rmtree(profile, ignore_errors=True)


def _wait(browser, ok, seconds):
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        try:
            if ok():
                return
        except Exception:  # (the page between two documents)
            pass
        time.sleep(0.2)
    raise AssertionError(f"the page did not get there in {seconds} s: {_status(browser)}")


_MODEL = "const m = Bokeh.documents[0].get_model_by_name(arguments[0]);"


def _column(browser, source, column):
    return browser.execute_script(
        _MODEL + "const c = m.data[arguments[1]];"
        "return Array.from(c, x => (x && x.length !== undefined && typeof x !== 'string')"
        " ? Array.from(x) : x);",
        source,
        column,
    )


def _status(browser) -> str:
    return browser.execute_script(_MODEL + "return m.text;", "status")


def _set(browser, name, value):
    browser.execute_script(_MODEL + "m.value = arguments[1];", name, value)


# Click a button by its model name (its view's click(), as a mouse click does).
_CLICK = """
const find = (v, name) => {
  if (v.model && v.model.name === name) { return v; }
  for (const c of (v.child_views || [])) { const f = find(c, name); if (f) { return f; } }
  return null;
};
for (const root of Object.values(Bokeh.index)) {
  const v = find(root, arguments[0]);
  if (v) { v.click(); return true; }
}
return false;
"""


def _click(browser, name):
    assert browser.execute_script(_CLICK, name), f"no button {name!r} on the page"


def _numbers(browser) -> dict:
    names = _column(browser, "numbers", "name")
    values = _column(browser, "numbers", "value")
    return {n: (math.nan if v is None else float(v)) for n, v in zip(names, values)}


def _download(browser, button) -> bytes:
    """The file a download button hands over (the "download" source emptied first, so that
    the same file twice is seen too)."""
    browser.execute_script(_MODEL + "m.data = {name: [], mime: [], b64: []};", "download")
    _click(browser, button)
    _wait(browser, lambda: len(_column(browser, "download", "b64")) > 0, SOLVE_S)
    return base64.b64decode(_column(browser, "download", "b64")[0])


def _value(browser, name):
    return browser.execute_script(_MODEL + "return m.value;", name)


def _on_worker(app, fn, seconds):
    """fn() run as a job of the page's worker: after the page's own solves, and none
    beside it (the explorer is the page's)."""
    done, box = threading.Event(), {}

    def job():
        try:
            box["value"] = fn()
        except BaseException as e:  # (raised again in the test)
            box["error"] = e
        finally:
            done.set()

    app.worker.submit(job)
    assert done.wait(seconds), f"the worker's job did not finish in {seconds} s"
    if "error" in box:
        raise box["error"]
    return box["value"]


# `fr.grasp` of a finger file's text (as `finray grasp` solves the file), once per text.
_GRASPS: dict = {}


def _grasp_of_file(text):
    if text not in _GRASPS:
        finger, settings = fio.loads_finger(text)
        _GRASPS[text] = fr.grasp(finger, **settings.grasp.grasp_kwargs())
    return _GRASPS[text]


def _finray_grasp(path, out):
    """`finray grasp PATH --out OUT` in this process: (exit code, its output, the
    `GraspSolution` its `fr.grasp` returned), that grasp kept as the file's."""
    from test_cli import run

    solved, real = [], fr.grasp

    def grasp(*args, **kwargs):
        solved.append(real(*args, **kwargs))
        return solved[-1]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fr, "grasp", grasp)
        code, stdout, err = run(["grasp", str(path), "--out", str(out)])
    assert len(solved) == 1, stdout + err
    _GRASPS[pathlib.Path(path).read_text()] = solved[0]
    return code, stdout + err, solved[0]


# --------------------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------------------


def test_moving_the_clamp_length_resolves_the_grasp_as_grasp_does(page, tmp_path):
    """A move of the back clamp length (20 to 22 mm: re-solved from the previous
    equilibrium by one Newton solve) changes the contact force and the drawn finger; the
    page's TOML download, read by `finray grasp` (`fr.grasp` of the file, on its own cuts:
    the same as the page's here), solves to the same contact force, actuator force and
    front beam to 1e-9, and its JSON output holds that contact force."""
    app, browser = page
    before = _numbers(browser)
    lines_before = _column(browser, "finger_lines", "xs")
    _set(browser, "back_clamp_length", 22.0)
    _wait(
        browser,
        lambda: (
            _numbers(browser)["contact_force"] != before["contact_force"]
            and "converged" in _status(browser)
        ),
        SOLVE_S,
    )
    assert app.explorer.state.how == "warm"  # (the slider's solve, not the closing path)
    after = _numbers(browser)
    lines = _column(browser, "finger_lines", "xs"), _column(browser, "finger_lines", "ys")
    assert lines[0][0] != lines_before[0]  # (the drawn front beam moved)
    text = _download(browser, "download_toml").decode()
    finger, _ = fio.loads_finger(text)
    assert float(finger.adaptor.back_clamp_length) == 22.0
    path, out = tmp_path / "design.toml", tmp_path / "g.json"
    path.write_text(text)
    code, output, g = _finray_grasp(path, out)
    assert code == 0, output
    assert g.converged
    assert abs(float(g.contact.normal_force) - after["contact_force"]) <= 1e-9
    assert abs(float(g.contact.actuator_force) - after["actuator_force"]) <= 1e-9
    front = np.asarray(g.solution.front.position)
    np.testing.assert_allclose(lines[0][0], front[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(lines[1][0], front[:, 2], rtol=0, atol=1e-9)
    doc = json.loads(out.read_text())
    assert abs(doc["contact"]["normal_force"] - after["contact_force"]) <= 1e-9


@pytest.mark.slow
def test_an_actuator_force_past_the_limit_says_so_and_keeps_the_page(page):
    """25 N is more than Finger-1 presses the 18 mm cylinder with (its force peaks near
    18 N, at 12 mm of closing): the status says the load lies beyond the limit, the last
    good design stays drawn, and the page goes on (closed by displacement again, at the
    actuator force it had). (The closing path to the peak takes tens of seconds.)"""
    app, browser = page
    good = _numbers(browser)
    xs = _column(browser, "finger_lines", "xs")
    force = _value(browser, "actuator_force")
    _set(browser, "actuator_force", 25.0)
    browser.execute_script(_MODEL + "m.active = 1;", "closing_kind")
    try:
        _wait(browser, lambda: "beyond the limit load" in _status(browser), LIMIT_S)
        assert "peaks near 18." in _status(browser)
        # (the kept design: the one drawn before, re-solved at the same values on the way)
        assert abs(_numbers(browser)["contact_force"] - good["contact_force"]) <= 1e-9
        for a, b in zip(_column(browser, "finger_lines", "xs"), xs, strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    finally:
        browser.execute_script(_MODEL + "m.active = 0;", "closing_kind")
        _set(browser, "actuator_force", force)
        _wait(browser, lambda: "converged" in _status(browser), SOLVE_S)


@pytest.mark.parametrize(
    "value, words",
    [("NaN", "finite number"), (55.0, "outside its bounds")],
)
def test_bad_values_are_refused_on_the_page(page, value, words):
    """A refused value says why, naming the control, and solves nothing; the control's
    value before is then set again."""
    app, browser = page
    good = _numbers(browser)
    kept = _value(browser, "back_clamp_length")
    browser.execute_script(
        _MODEL + "m.value = (arguments[1] === 'NaN') ? NaN : arguments[1];",
        "back_clamp_length",
        value,
    )
    _wait(browser, lambda: "refused" in _status(browser), SOLVE_S)
    status = _status(browser)
    assert words in status and "back_clamp_length" in status, status
    assert _numbers(browser)["contact_force"] == good["contact_force"]  # (nothing solved)
    _set(browser, "back_clamp_length", kept)
    _wait(browser, lambda: "converged" in _status(browser), SOLVE_S)


def test_gradient_bars_numbers_json_and_screenshot(page):
    """The gradient of the contact force in every design value is drawn; the numbers'
    JSON holds the page's numbers; a screenshot is kept as the test's artefact."""
    app, browser = page
    _wait(browser, lambda: len(_column(browser, "gradient", "scaled")) > 5, SOLVE_S)
    names = _column(browser, "gradient", "name")
    assert "back_clamp_length" in names and "E" in names
    assert all(math.isfinite(x) for x in _column(browser, "gradient", "scaled"))
    doc = json.loads(_download(browser, "download_json"))
    assert doc["status"] == "converged"
    assert doc["numbers"]["contact_force"] == _numbers(browser)["contact_force"]
    assert set(doc["gradient"]["d_objective"]) == set(names)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shot = ARTIFACTS / "explore.png"
    browser.save_screenshot(str(shot))
    assert shot.stat().st_size > 20_000


def _grasp_of_page(app, choices, values):
    """`fr.grasp` of the page's design under `choices`, as the explorer solves it: at the
    penalty stiffnesses its program holds, on the program's segment table."""
    from finray_jax._grasp_inputs import with_stiffness

    ex = app.explorer
    prog = ex.program(choices)
    finger = with_stiffness(ex.design(choices, values), *prog.stiffness)
    return fr.grasp(
        finger,
        float(values["closing"]),
        direction=ex.direction,
        symmetric=ex.symmetric,
        topology=prog.topology,
    )


def test_holding_force_button_shows_the_release_peak_and_its_gradient(page):
    """The holding force drawn equals, to 1e-9, `fr.release_force(...)`.peak of `fr.grasp`
    of the page's TOML download (traced at the file's pull step and friction, as `finray
    grasp --release` does), and with "holding force" chosen its gradient bars are drawn."""
    app, browser = page
    _click(browser, "holding")
    _wait(browser, lambda: math.isfinite(_numbers(browser)["holding_force"]), LIMIT_S)
    text = _download(browser, "download_toml").decode()
    grasp_settings = fio.loads_finger(text)[1].grasp
    g = _grasp_of_file(text)
    assert g.converged
    trace = fr.release_force(
        g, step=grasp_settings.pull_step, friction=grasp_settings.friction, topology=g.topology
    )
    assert abs(_numbers(browser)["holding_force"] - trace.peak) <= 1e-9
    _set(browser, "objective", "holding force")
    try:
        _wait(browser, lambda: len(_column(browser, "gradient", "scaled")) > 5, SOLVE_S)
        assert all(math.isfinite(x) for x in _column(browser, "gradient", "scaled"))
    finally:
        _set(browser, "objective", "contact force")


def test_step_uphill_raises_the_contact_force_within_bounds(page):
    app, browser = page
    from finray_jax._explore_design import BY_NAME

    _wait(browser, lambda: len(_column(browser, "gradient", "scaled")) > 5, SOLVE_S)
    names = _column(browser, "gradient", "name")
    before = {n: _value(browser, n) for n in names}
    force = _numbers(browser)["contact_force"]
    _click(browser, "uphill")
    _wait(
        browser,
        lambda: _numbers(browser)["contact_force"] != force and "converged" in _status(browser),
        SOLVE_S,
    )
    after = {n: _value(browser, n) for n in names}
    assert after != before
    assert all(BY_NAME[n].lo <= after[n] <= BY_NAME[n].hi for n in names)
    assert _numbers(browser)["contact_force"] > force


def test_original_vs_modified_adaptor_side_by_side(page):
    """Both adaptors' grasps are drawn (each solved from the open gripper); to 1e-9, the
    modified adaptor's numbers are the page's own (the design drawn has the file's
    adaptor, the modified one) and the original adaptor's are `fr.grasp`'s of the page's
    design with that adaptor; the two differ."""
    app, browser = page
    state = app.explorer.state
    assert state.choices.adaptor == "modified"
    drawn = _numbers(browser)
    _click(browser, "compare")
    _wait(browser, lambda: len(_column(browser, "compared", "adaptor")) == 2, LIMIT_S)
    for kind in ("original", "modified"):
        assert browser.execute_script(_MODEL + "return m !== null;", f"compare_{kind}")
    numbers = {"normal_force": "contact_force", "actuator_force": "actuator_force"}
    shown = {}
    for i, kind in enumerate(_column(browser, "compared", "adaptor")):
        row = {key: _column(browser, "compared", key)[i] for key in numbers}
        if kind == "modified":
            expected = {key: drawn[name] for key, name in numbers.items()}
        else:
            c = dataclasses.replace(state.choices, adaptor=kind)
            g = _grasp_of_page(app, c, state.values)
            assert g.converged
            expected = {key: float(getattr(g.contact, key)) for key in numbers}
        for key in numbers:
            assert abs(row[key] - expected[key]) <= 1e-9, (kind, key, row, expected)
        shown[kind] = row["normal_force"]
    assert abs(shown["original"] - shown["modified"]) > 1e-3


# --------------------------------------------------------------------------------------
# Without a browser: the command line and the controls
# --------------------------------------------------------------------------------------


def test_explore_without_bokeh_says_how_to_install_it(monkeypatch):
    import importlib.util

    from test_cli import run

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "bokeh" else real(name, *a)
    )
    code, _, err = run(["explore", "--no-browser"])
    assert code == 1 and "pip install 'finray_jax[explore]'" in err, err


def test_explore_options_and_file_are_checked():
    from test_cli import run

    code, _, err = run(["explore", "--port", "70000"])
    assert code == 1 and "--port" in err and "70000" in err
    code, _, err = run(["explore", "no_such_finger.toml", "--no-browser"])
    assert code == 1 and "no_such_finger.toml" in err


def test_controls_refuse_values_naming_the_control():
    from finray_jax._explore_design import Choices, ControlError, check_value

    with pytest.raises(ControlError, match=r"back_clamp_length.*finite number"):
        check_value("back_clamp_length", float("nan"))
    with pytest.raises(ControlError, match=r"\(E\) = 99 MPa: outside its bounds 2\.\.60"):
        check_value("E", 99.0)
    with pytest.raises(ControlError, match="crossbeam_count = 0"):
        Choices(crossbeam_count=0).checked()
    assert check_value("E", "12.5") == 12.5


def test_a_step_uphill_moves_the_steepest_control_by_two_percent_within_bounds():
    pytest.importorskip("bokeh")
    from finray_jax._explore_design import BY_NAME
    from finray_jax._explore_page_tools import UPHILL_STEP, uphill

    values = {"E": 12.0, "back_clamp_length": 39.9, "crossbeam_angle": 0.0}
    grad = {"E": 0.5, "back_clamp_length": 10.0, "crossbeam_angle": -0.001}
    new = uphill(grad, values)
    assert new["back_clamp_length"] == BY_NAME["back_clamp_length"].hi  # (kept in bounds)
    e = BY_NAME["E"]
    step = UPHILL_STEP * (0.5 * (e.hi - e.lo)) / (10.0 * 40.0) * (e.hi - e.lo)
    assert new["E"] == pytest.approx(round((12.0 + step) / e.step) * e.step)
    assert new["crossbeam_angle"] <= 0.0


def _contact_stiffness(state) -> tuple:
    c = state.finger.contact
    return tuple(float(k) for k in (c.stiffness, c.support_stiffness, c.member_stiffness))


def _solved_from(explorer, state, values):
    """The explorer's solve of `values` started from `state`, as a control moved from
    state's design re-solves it (from the tangent's prediction: the sensitivities at
    state), leaving the explorer's own state and sensitivities as they were."""
    from finray_jax._explore_grad import sensitivities

    kept = explorer.state, explorer.sensitivities
    explorer.state, explorer.sensitivities = state, sensitivities(explorer, state)
    try:
        return explorer.solve(state.choices, values)
    finally:
        explorer.state, explorer.sensitivities = kept


@pytest.mark.slow
def test_holding_force_gradient_matches_a_central_difference(server):
    """The holding force's gradient (`holding_gradient`: the optimiser's objective at the
    peak's pull) against a central difference of the holding force the page computes
    (`Explorer.holding`), in the back clamp length, at the finger file's design: the
    page's explorer solves the design and its two neighbours as a moved control does (from
    the nearby equilibrium, at the same penalty stiffnesses), on the page's worker. The
    neighbour the gradient points to holds more, the other less."""
    from finray_jax._explore_grad import holding_gradient

    app, _ = server
    assert app.worker.wait_idle(READY_S) and app.ready, app.error
    ex = app.explorer
    name, h = "back_clamp_length", 0.5

    def central_difference():
        base = _solved_from(ex, app.first, app.values)
        state = ex.holding(base)
        value, grad = holding_gradient(ex, state)
        f = {}
        for sign in (1.0, -1.0):
            moved = _solved_from(ex, base, {**app.values, name: app.values[name] + sign * h})
            assert moved.converged and _contact_stiffness(moved) == _contact_stiffness(base)
            f[sign] = ex.holding(moved).holding
        return state, value, grad[name], f

    state, value, grad, f = _on_worker(app, central_difference, LIMIT_S)
    assert state.holding > 0
    assert abs(value - state.holding) <= 1e-9 * abs(state.holding)  # (the same equilibrium)
    fd = (f[1.0] - f[-1.0]) / (2 * h)
    # The central difference's own error: h^2/6 F''' from truncation (about 2.4e-6 N/mm
    # here, 3.4e-4 of the derivative: F''' ~ 6e-5 N/mm^4 at h = 0.5 mm) and the solves'
    # residuals over 2h (~1e-10 N / 1 mm, negligible); 1e-3 of the derivative bounds both.
    assert abs(fd - grad) <= 1e-3 * abs(grad)
    up = math.copysign(1.0, grad)
    assert f[up] > state.holding > f[-up]


def test_sensitivities_are_taken_at_the_penalties_the_state_was_solved_at(server):
    """A program's penalty stiffnesses rise when a later grasp's penetration limit does
    not hold; the derivatives at an earlier state stay those of its own equilibrium, at
    the stiffnesses it was solved at (its finger's [contact] table), not the program's."""
    from finray_jax._explore_grad import sensitivities

    app, _ = server
    assert app.worker.wait_idle(READY_S) and app.ready, app.error
    ex, state = app.explorer, app.first
    prog = ex.program(state.choices)

    def at_raised_penalties():
        kept = prog.stiffness
        prog.stiffness = tuple(4.0 * k for k in _contact_stiffness(state))
        try:
            return sensitivities(ex, state)
        finally:
            prog.stiffness = kept

    sens = _on_worker(app, at_raised_penalties, SOLVE_S)
    y = np.asarray(state.solution.unknowns)
    # Newton from the state's own equilibrium stays there: the same unknowns to its
    # tolerance (1e-10 on the scaled unknowns); the equilibrium at four times the
    # penalties lies ~2 % of the largest unknown away.
    assert np.max(np.abs(sens.unknowns - y)) <= 1e-8 * np.max(np.abs(y))
    force = float(state.contact.normal_force)
    assert sens.objectives[0] == pytest.approx(force, rel=1e-9)
