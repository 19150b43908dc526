"""The design explorer's page (Bokeh): the controls, the figures and numbers, and what
each button does. Every solve runs on the app's worker thread; its result comes back to
the page through the document's next-tick callbacks, so the page stays live while a
design solves (or compiles), and a refused or failed design leaves the last good state
drawn with the reason above it.

Models carry names (`Bokeh.documents[0].get_model_by_name(...)` in the browser): each
numeric control by its control name, the choices ("mode", "adaptor", "crossbeam_count",
"object_kind", "closing_kind"), "status", "numbers", "finger_lines", "gradient",
"compared" (the adaptors' numbers side by side), "download" (the last download's file,
base64) and the buttons.
"""

from __future__ import annotations

import functools

import numpy as np
from bokeh.layouts import column, row
from bokeh.models import (
    Button,
    ColumnDataSource,
    CustomJS,
    Div,
    RadioButtonGroup,
    Select,
    Slider,
    Spinner,
)
from bokeh.plotting import figure

from ._explore_app import REFUSED, App
from ._explore_design import (
    ADAPTORS,
    BY_NAME,
    CLOSINGS,
    CONTROLS,
    MODES,
    OBJECT_KINDS,
    Choices,
    active,
)
from ._explore_grad import HOLDING, OBJECTIVES, holding_gradient, sensitivities
from ._explore_page_tools import (
    DOWNLOAD_JS,
    compare_views,
    download_files,
    empty,
    figure_files,
    numbers_html,
    status_html,
    uphill,
)
from ._explore_views import NUMBERS, status_of, view_of

POLL_MS = 250  # how often a page waiting for the start-up's preparation looks again


class Page:
    """One browser page of the explorer."""

    def __init__(self, doc, app: App):
        self.doc, self.app = doc, app
        self.pending = None  # the latest request not yet handed to the worker
        self.busy = False
        self.quiet = False  # (set while the page itself moves controls)
        self.state = None  # the state drawn
        self.sens = None  # its sensitivities, when computed
        self._widgets()
        self._figures()
        doc.title = "finray explore"
        doc.add_root(self._layout())
        # (in no layout: roots of their own)
        for source in (self.download, self.numbers, self.compared):
            doc.add_root(source)
        self._poll = doc.add_periodic_callback(self._await_ready, POLL_MS)
        self._await_ready()

    # ----------------------------------------------------------------------------------
    # Building the page
    # ----------------------------------------------------------------------------------

    def _widgets(self) -> None:
        c, v = self.app.choices, self.app.values
        self.mode = RadioButtonGroup(labels=list(MODES), active=MODES.index(c.mode), name="mode")
        self.adaptor = Select(
            title="adaptor", options=list(ADAPTORS), value=c.adaptor, name="adaptor"
        )
        self.count = Spinner(
            title="crossbeam count", low=1, high=12, step=1, value=c.crossbeam_count,
            name="crossbeam_count",
        )  # fmt: skip
        self.object_kind = Select(
            title="object", options=list(OBJECT_KINDS), value=c.object_kind, name="object_kind"
        )
        self.closing_kind = RadioButtonGroup(
            labels=["closing displacement", "actuator force"],
            active=CLOSINGS.index(c.closing),
            name="closing_kind",
        )
        self.sliders = {}
        for ctl in CONTROLS:
            title = f"{ctl.label} ({ctl.unit})" if ctl.unit else ctl.label
            s = Slider(
                title=title, start=ctl.lo, end=ctl.hi, step=ctl.step, value=v[ctl.name],
                name=ctl.name, width=300,
            )  # fmt: skip
            s.on_change("value", self._on_control)
            self.sliders[ctl.name] = s
        for w in (self.adaptor, self.count, self.object_kind):
            w.on_change("value", self._on_control)
        for w in (self.mode, self.closing_kind):
            w.on_change("active", self._on_control)
        self.objective = Select(
            title="objective", options=list(OBJECTIVES) + [HOLDING], value=OBJECTIVES[0],
            name="objective",
        )  # fmt: skip
        self.objective.on_change("value", lambda attr, old, new: self._show_gradient())
        self.buttons = {}
        for name, label, fn in (
            ("holding", "compute holding force", self._on_holding),
            ("uphill", "step uphill", self._on_uphill),
            ("compare", "original vs modified adaptor", self._on_compare),
            ("download_toml", "finger TOML", lambda: self._download("toml")),
            ("download_json", "numbers JSON", lambda: self._download("json")),
            ("download_png", "figure PNG", lambda: self._download("png")),
            ("download_svg", "figure SVG", lambda: self._download("svg")),
        ):
            b = Button(label=label, name=name, width=140)
            b.on_click(fn)
            self.buttons[name] = b
        self.status = Div(text=status_html("preparing", "starting"), name="status", width=640)
        self.download = ColumnDataSource(empty("download"), name="download")
        self.download.js_on_change("data", CustomJS(args={"src": self.download}, code=DOWNLOAD_JS))

    def _figures(self) -> None:
        self.lines = ColumnDataSource({"xs": [], "ys": [], "color": []}, name="finger_lines")
        self.outline = ColumnDataSource({"xs": [], "ys": []}, name="outline")
        self.objects = ColumnDataSource({"xs": [], "ys": []}, name="objects")
        self.pressure = ColumnDataSource({"s": [], "q": []}, name="pressure")
        self.cb = ColumnDataSource({"index": [], "force": []}, name="crossbeam_forces")
        self.numbers = ColumnDataSource(empty("numbers"), name="numbers")
        self.gradient = ColumnDataSource(empty("gradient"), name="gradient")
        self.compared = ColumnDataSource(empty("compare"), name="compared")
        f = figure(title="grasp", match_aspect=True, width=560, height=520, name="finger_figure")
        f.multi_line("xs", "ys", source=self.outline, color="#aaaaaa", line_dash="dashed")
        f.patches(
            "xs", "ys", source=self.objects, fill_color="#f4b183", line_color="#c55a11", alpha=0.8
        )
        f.multi_line("xs", "ys", source=self.lines, color="color", line_width=2)
        f.xaxis.axis_label, f.yaxis.axis_label = "x (mm)", "z (mm)"
        self.finger_figure = f
        p = figure(title="contact pressure on the front beam", width=420, height=250)
        p.line("s", "q", source=self.pressure, line_width=2)
        p.xaxis.axis_label, p.yaxis.axis_label = "s (mm)", "q (N/mm)"
        b = figure(title="crossbeam axial forces (tension > 0)", width=420, height=250)
        b.vbar(x="index", top="force", width=0.7, source=self.cb)
        b.xaxis.axis_label, b.yaxis.axis_label = "crossbeam (from the base)", "N"
        names = [ctl.name for ctl in CONTROLS]
        g = figure(
            title="gradient x range of each control",
            y_range=names[::-1], width=560, height=420, name="gradient_figure",
        )  # fmt: skip
        g.hbar(y="name", right="scaled", height=0.7, color="color", source=self.gradient)
        self.gradient_figure = g
        self.table = Div(text="", name="numbers_table", width=420)
        self.compare = row(Div(text=""), name="compare_row")
        self.side = column(p, b, self.table)

    def _layout(self):
        controls = column(
            Div(text="<b>finray explore</b>"),
            self.mode, self.adaptor, self.count, self.object_kind, self.closing_kind,
            *self.sliders.values(),
            self.objective, *self.buttons.values(),
            width=320,
        )  # fmt: skip
        views = column(
            self.status, row(self.finger_figure, self.side), self.gradient_figure, self.compare
        )
        return row(controls, views)

    # ----------------------------------------------------------------------------------
    # Start-up
    # ----------------------------------------------------------------------------------

    def _await_ready(self) -> None:
        app = self.app
        if app.preparing:
            self.status.text = status_html(
                "preparing", f"preparing: {app.preparing} (once per start)"
            )
            self._enable(False)
            return
        self.doc.remove_periodic_callback(self._poll)
        if app.first is None:
            self.status.text = status_html(
                "error", f"the first design could not be solved: {app.error}"
            )
            return
        self._enable(True)
        self._show(app.first, app.first_view, None)
        self.sens = app.explorer.sensitivities
        self._show_gradient()

    def _enable(self, on: bool) -> None:
        for w in [
            *self.sliders.values(),
            *self.buttons.values(),
            self.mode,
            self.adaptor,
            self.count,
        ]:
            w.disabled = not on
        if on:
            self._disable_inactive(self.choices())

    def _disable_inactive(self, choices: Choices) -> None:
        act = set(active(choices))
        for name, s in self.sliders.items():
            s.disabled = name not in act
        self.object_kind.disabled = choices.mode != "grasp"
        self.closing_kind.disabled = choices.mode != "grasp"
        self.buttons["holding"].disabled = choices.mode != "grasp"

    # ----------------------------------------------------------------------------------
    # Controls -> solves on the worker -> the page
    # ----------------------------------------------------------------------------------

    def choices(self) -> Choices:
        return Choices(
            mode=MODES[self.mode.active],
            adaptor=self.adaptor.value,
            crossbeam_count=self.count.value,
            object_kind=self.object_kind.value,
            closing=CLOSINGS[self.closing_kind.active],
        )

    def values(self) -> dict:
        return {name: s.value for name, s in self.sliders.items()}

    def _on_control(self, attr, old, new) -> None:
        if self.quiet or not self.app.ready:
            return
        self.request()

    def request(self) -> None:
        """Solve the page's design (the latest one, when several wait)."""
        self.pending = (self.choices(), self.values())
        if not self.busy:
            self._hand_over()

    def _hand_over(self) -> None:
        choices, values = self.pending
        self.pending, self.busy = None, True
        try:
            choices = choices.checked()
        except REFUSED as e:
            self._refused(str(e))
            return
        self._disable_inactive(choices)
        if not self.app.explorer.compiled(choices):
            self.status.text = status_html(
                "preparing", "compiling: a new topology compiles once (about a minute)"
            )
        self.app.worker.submit(functools.partial(self._solve, choices, values))

    def _solve(self, choices, values) -> None:  # (on the worker)
        explorer = self.app.explorer
        try:
            state = explorer.solve(choices, values)
            view = view_of(state, explorer.symmetric) if state.converged else None
            self._later(self._show, state, view, None)
        except REFUSED as e:
            self._later(self._show, None, None, str(e))
            return
        finally:
            self._later(self._next)
        if state.converged and self.pending is None:
            explorer.sensitivities = sensitivities(explorer, state)
            self._later(self._set_sens, explorer.sensitivities, state)

    def _later(self, fn, *args) -> None:
        self.doc.add_next_tick_callback(functools.partial(fn, *args))

    def _next(self) -> None:
        self.busy = False
        if self.pending is not None:
            self._hand_over()

    def _refused(self, message: str) -> None:
        self.busy = False
        self.status.text = status_html(
            "error", f"refused: {message} (the last good design stays drawn)"
        )

    def _show(self, state, view, error) -> None:
        if error is not None:
            self.status.text = status_html(
                "error", f"refused: {error} (the last good design stays drawn)"
            )
            return
        kind, line = status_of(state)
        self.status.text = status_html(kind, line)
        if view is None:
            return
        self.state = state
        self.lines.data = view.lines
        self.outline.data = view.outline
        self.objects.data = view.objects
        self.pressure.data = view.pressure
        self.cb.data = view.crossbeams
        self._show_numbers(view.numbers)

    def _show_numbers(self, numbers: dict) -> None:
        rows = [(label, numbers[key], unit) for key, label, unit in NUMBERS]
        self.table.text = numbers_html(rows)
        self.numbers.data = {
            "name": [key for key, _, _ in NUMBERS],
            "label": [r[0] for r in rows],
            "value": np.asarray([r[1] for r in rows], float),
            "unit": [r[2] for r in rows],
        }

    def _set_sens(self, sens, state) -> None:
        if state is self.state:
            self.sens = sens
            self._show_gradient()

    def _gradient(self) -> dict | None:
        """The chosen objective's gradient at the drawn state (None: not known yet)."""
        if self.state is None:
            return None
        if self.objective.value == HOLDING:
            return self.state.holding_gradient
        return None if self.sens is None else self.sens.gradient(self.objective.value)

    def _show_gradient(self) -> None:
        objective = self.objective.value
        grad = self._gradient()
        if grad is None:
            self.gradient.data = empty("gradient")
            self.gradient_figure.title.text = (
                "gradient: press 'compute holding force' (value and gradient)"
                if objective == HOLDING
                else "gradient: computing"
            )
            return
        names = list(grad)
        scaled = [grad[n] * (BY_NAME[n].hi - BY_NAME[n].lo) for n in names]
        self.gradient.data = {
            "name": names,
            "value": np.asarray([grad[n] for n in names], float),
            "scaled": np.asarray(scaled, float),
            "color": ["#2ca02c" if s >= 0 else "#d62728" for s in scaled],
        }
        self.gradient_figure.title.text = f"d({objective}) x range of each control (first order)"

    # ----------------------------------------------------------------------------------
    # Buttons
    # ----------------------------------------------------------------------------------

    def _on_uphill(self) -> None:
        grad = self._gradient()
        if grad is None:
            self.status.text = status_html("error", "no gradient to step along yet")
            return
        new = uphill(grad, self.values())
        self.quiet = True
        try:
            for name, value in new.items():
                self.sliders[name].value = value
        finally:
            self.quiet = False
        self.request()

    def _on_holding(self) -> None:
        state = self.state
        if state is None or state.contact is None:
            return
        self.status.text = status_html(
            "preparing", "tracing the release for the holding force and its gradient"
        )

        def job():
            try:
                explorer = self.app.explorer
                done = explorer.holding(state)
                if done.holding == done.holding and done.holding > 0:  # (a peak to follow)
                    done.holding_gradient = holding_gradient(explorer, done)[1]
                self._later(self._show_holding, done)
            except REFUSED as e:
                self._later(self._show, None, None, str(e))

        self.app.worker.submit(job)

    def _show_holding(self, state) -> None:
        if self.state is not None and self.state.values == state.values:
            self.state = state
            self._show_numbers(view_of(state).numbers)
            self._show_gradient()
            self.status.text = status_html("ok", f"holding force: {state.holding_message}")

    def _on_compare(self) -> None:
        choices, values = self.choices(), self.values()
        self.status.text = status_html(
            "preparing", "solving the original and the modified adaptor (compiles once each)"
        )

        def job():
            try:
                views, numbers = compare_views(self.app.explorer, choices, values)
                self._later(self._show_compare, views, numbers)
            except REFUSED as e:
                self._later(self._show, None, None, str(e))

        self.app.worker.submit(job)

    def _show_compare(self, views, numbers) -> None:
        self.compare.children = views
        self.compared.data = numbers
        self.status.text = status_html("ok", "original vs modified adaptor: below")

    def _download(self, kind: str) -> None:
        if self.state is None:
            return
        state, sens, objective = self.state, self.sens, self.objective.value
        explorer = self.app.explorer
        if kind in ("toml", "json"):
            self.download.data = download_files(kind, state, explorer, sens, objective)
            return

        def job():
            self._later(self._set_download, figure_files(kind, state, explorer))

        self.app.worker.submit(job)

    def _set_download(self, data) -> None:
        self.download.data = data


def make_document(app: App, doc) -> None:
    Page(doc, app)
