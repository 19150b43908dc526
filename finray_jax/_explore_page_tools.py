"""The design explorer page's helpers: the status line, the projected gradient step, the
downloads (finger file, numbers, figure) and the side-by-side adaptors."""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import json

import numpy as np
from bokeh.models import ColumnDataSource
from bokeh.plotting import figure

from ._explore_design import BY_NAME
from ._explore_views import json_of, toml_of, view_of
from ._plot_finger import pyplot
from .plot import grasp_figure, solution_figure

UPHILL_STEP = 0.02  # of its range: the largest move of one control in a step uphill

# Save the "download" source's file in the browser (set by the server, base64).
DOWNLOAD_JS = """
const d = src.data;
if (!d.b64 || d.b64.length === 0) { return; }
const bin = atob(d.b64[0]);
const bytes = new Uint8Array(bin.length);
for (let i = 0; i < bin.length; i++) { bytes[i] = bin.charCodeAt(i); }
const a = document.createElement("a");
a.href = URL.createObjectURL(new Blob([bytes], {type: d.mime[0]}));
a.download = d.name[0];
document.body.appendChild(a);
a.click();
a.remove();
"""

_COLUMNS = {
    "download": ("name", "mime", "b64"),
    "numbers": ("name", "label", "value", "unit"),
    "gradient": ("name", "value", "scaled", "color"),
    "compare": ("adaptor", "normal_force", "actuator_force"),
}
_COLORS = {"ok": "#1a7f37", "preparing": "#9a6700", "error": "#cf222e"}


def empty(kind: str) -> dict:
    return {c: [] for c in _COLUMNS[kind]}


def status_html(kind: str, text: str) -> str:
    """The status line: ok, preparing or error (the class names it, for the tests)."""
    return (
        f'<div class="finray-status finray-{kind}" style="color:{_COLORS[kind]};'
        f'font-weight:bold">{html.escape(text)}</div>'
    )


def numbers_html(rows) -> str:
    """The numbers as an HTML table: (label, value, unit) rows; NaN shows as "-"."""
    cells = []
    for label, value, unit in rows:
        v = "-" if value != value else f"{value:.6g}"
        cells.append(
            f"<tr><td>{html.escape(label)}</td><td style='text-align:right'>{v}</td>"
            f"<td>{html.escape(unit)}</td></tr>"
        )
    return "<table style='border-spacing:12px 2px'>" + "".join(cells) + "</table>"


def uphill(gradient: dict, values: dict) -> dict:
    """One projected gradient step in the controls' scaled coordinates u = (x - lo) /
    (hi - lo): the control with the largest scaled derivative moves UPHILL_STEP of its
    range, the others in proportion, each then kept within its bounds."""
    scaled = {n: g * (BY_NAME[n].hi - BY_NAME[n].lo) for n, g in gradient.items()}
    top = max((abs(g) for g in scaled.values()), default=0.0)
    if not top > 0:
        return {}
    out = {}
    for n, g in scaled.items():
        c = BY_NAME[n]
        x = float(values[n]) + UPHILL_STEP * g / top * (c.hi - c.lo)
        out[n] = float(np.clip(round(x / c.step) * c.step if c.step else x, c.lo, c.hi))
    return out


def _file(name: str, mime: str, data: bytes) -> dict:
    return {"name": [name], "mime": [mime], "b64": [base64.b64encode(data).decode("ascii")]}


def download_files(kind: str, state, explorer, sens=None, objective=None) -> dict:
    """The "download" source's data for the finger file or the numbers."""
    if kind == "toml":
        return _file("finray_design.toml", "application/toml", toml_of(state, explorer).encode())
    doc = json_of(state, sens, objective)
    return _file("finray_design.json", "application/json", json.dumps(doc, indent=2).encode())


def figure_files(kind: str, state, explorer) -> dict:
    """The "download" source's data for the state's figure (PNG or SVG, matplotlib)."""
    if state.contact is not None:
        fig = grasp_figure([explorer.grasp_solution(state)], ["explorer design"])
    else:
        fig = solution_figure(state.solution, state.finger, title="explorer design (load case)")
    buf = io.BytesIO()
    fig.savefig(buf, format=kind, dpi=120)
    pyplot().close(fig)
    mime = "image/png" if kind == "png" else "image/svg+xml"
    return _file(f"finray_design.{kind}", mime, buf.getvalue())


def compare_views(explorer, choices, values) -> tuple[list, dict]:
    """Figures of the design with the original and with the modified adaptor (the grasp
    of each: the closing path from the open gripper), and their numbers (the "compare"
    source's data: adaptor, contact and actuator force, NaN where a grasp failed)."""
    out, numbers = [], empty("compare")
    for kind in ("original", "modified"):
        c = dataclasses.replace(choices, adaptor=kind, mode="grasp")
        state = explorer.solve_aside(c, values)
        numbers["adaptor"].append(kind)
        for key in ("normal_force", "actuator_force"):
            v = float(getattr(state.contact, key)) if state.converged else float("nan")
            numbers[key].append(v)
        f = figure(title=_compare_title(kind, state), match_aspect=True, width=380, height=380)
        if state.converged:
            v = view_of(state, explorer.symmetric)
            f.multi_line(
                "xs", "ys", source=ColumnDataSource(v.outline), color="#aaaaaa", line_dash="dashed"
            )
            f.patches(
                "xs", "ys", source=ColumnDataSource(v.objects), fill_color="#f4b183", alpha=0.8
            )
            f.multi_line("xs", "ys", source=ColumnDataSource(v.lines), color="color", line_width=2)
        f.name = f"compare_{kind}"
        out.append(f)
    return out, numbers


def _compare_title(kind: str, state) -> str:
    if not state.converged:
        return f"{kind} adaptor: {state.status}"
    c = state.contact
    return (
        f"{kind}: contact {float(c.normal_force):.3f} N, actuator {float(c.actuator_force):.3f} N"
    )
