"""Plots of a finger solution and of grasps (matplotlib), on the public API.

plot_finger: the deformed finger in the x-z plane, the undeformed one in grey, the adaptor
    (base markers, clamped lengths, support) and objects, with a legend of its symbols.
plot_internal_forces: along the front and back beams, the axial force n.d3, shear force
    n.d1 and bending moment m.d2 (the beam's own frame), or n_x, n_z, m_y (world frame).
solution_figure / save_solution_figure: both, in one labelled figure.
plot_grasp / grasp_figure: grasps with their objects, closing and contact pressure.
release_figure / release_comparison_figure: holding force against pull distance.
clamp_study_figure: the clamp-length study.

Units: mm, N, N mm. The figure helpers build a `matplotlib.figure.Figure` directly (no
pyplot, so they work on any backend); the `ax=None` paths use pyplot, switching to the Agg
backend on a Linux machine without a display.
"""

from __future__ import annotations

import numpy as np

from . import Finger
from ._plot_finger import BACK_COLOR as BACK_COLOR
from ._plot_finger import BASE_MARKERS as BASE_MARKERS
from ._plot_finger import CROSSBEAM_COLOR as CROSSBEAM_COLOR
from ._plot_finger import FRONT_COLOR as FRONT_COLOR
from ._plot_finger import LOAD_COLOR as LOAD_COLOR
from ._plot_finger import UNDEFORMED_COLOR as UNDEFORMED_COLOR
from ._plot_finger import plot_finger as plot_finger
from ._plot_finger import pyplot
from ._plot_finger import save_figure as save_figure
from ._plot_grasp import clamp_study_figure as clamp_study_figure
from ._plot_grasp import grasp_figure as grasp_figure
from ._plot_grasp import plot_grasp as plot_grasp
from ._plot_grasp import release_comparison_figure as release_comparison_figure
from ._plot_grasp import release_figure as release_figure


def _material_components(b):
    """Axial force n.d3, shear force n.d1 and bending moment m.d2 (N, N, N mm)."""
    R = np.asarray(b.frame, dtype=np.float64)
    n = np.asarray(b.force, dtype=np.float64)
    m = np.asarray(b.moment, dtype=np.float64)
    return (
        np.einsum("ni,ni->n", n, R[:, :, 2]),
        np.einsum("ni,ni->n", n, R[:, :, 0]),
        np.einsum("ni,ni->n", m, R[:, :, 1]),
    )


def _outer_points(s: np.ndarray) -> np.ndarray:
    """Mask keeping the first and last of each run of equal s (several jumps at one point,
    e.g. a crossbeam joint and a load, are drawn as one jump)."""
    same_prev = np.r_[False, s[1:] == s[:-1]]
    same_next = np.r_[s[:-1] == s[1:], False]
    return ~(same_prev & same_next)


def plot_internal_forces(
    sol, axes=None, *, components: str = "world", finger: Finger | None = None
):
    """Internal force and moment along the front and back beams.

    components: "world" plots n_x(s), n_z(s) (N) and m_y(s) (N mm), world frame;
        "material" plots the axial force n.d3, the shear force n.d1 (N) and the bending
        moment m.d2 (N mm).
    axes: three axes (new ones if None). finger: if given, the crossbeam joints are marked
        with faint vertical lines (blue on the front beam, red on the back beam).
    n(s), m(s) are what the material at s+ exerts on s-. Returns the axes.
    """
    if components not in ("world", "material"):
        raise ValueError(f"components must be 'world' or 'material', got {components!r}")
    if axes is None:
        _, axes = pyplot().subplots(3, 1, figsize=(6, 7), sharex=True)
    axes = list(np.ravel(axes))
    if len(axes) != 3:
        raise ValueError(f"plot_internal_forces needs 3 axes, got {len(axes)}")
    if components == "world":
        labels = (
            "force $n_x$ (N)\nworld frame",
            "force $n_z$ (N)\nworld frame",
            "moment $m_y$ (N mm)\nworld frame",
        )
    else:
        labels = (
            "axial force $n\\cdot d_3$ (N)\nbeam frame, + tension",
            "shear force $n\\cdot d_1$ (N)\nbeam frame",
            "bending moment\n$m\\cdot d_2$ (N mm), beam frame",
        )
    for b, color, name in (
        (sol.front, FRONT_COLOR, "front beam"),
        (sol.back, BACK_COLOR, "back beam"),
    ):
        s = np.asarray(b.s, dtype=np.float64)
        if components == "world":
            n = np.asarray(b.force, dtype=np.float64)
            m = np.asarray(b.moment, dtype=np.float64)
            ys = (n[:, 0], n[:, 2], m[:, 1])
        else:
            ys = _material_components(b)
        keep = _outer_points(s)
        for ax, y in zip(axes, ys, strict=True):
            ax.plot(s[keep], y[keep], color=color, lw=1.8, label=name)
    if finger is not None:
        for key, color in (("front_s", FRONT_COLOR), ("back_s", BACK_COLOR)):
            for a in np.asarray(getattr(finger.crossbeams, key), dtype=np.float64):
                for ax in axes:
                    ax.axvline(a, color=color, alpha=0.18, lw=0.8, zorder=0)
        axes[0].plot([], [], color="0.6", alpha=0.5, lw=0.8, label="crossbeam joints")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_ylabel(label)
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.grid(True, lw=0.4, alpha=0.5)
    axes[-1].set_xlabel("arc length s from the base (mm)")
    axes[0].legend(loc="best", fontsize="x-small")
    return axes


def solution_figure(sol, finger: Finger, *, title: str | None = None, components: str = "material"):
    """A figure like the paper's Fig. 3 (b-e): the deformed shape (left) and the internal
    force and moment along the front and back beams (right): axial force, shear force and
    bending moment in the beam's own frame ("material"), or n_x, n_z, m_y ("world").
    Returns a matplotlib Figure (no pyplot)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 7.5), layout="constrained")
    gs = fig.add_gridspec(3, 2, width_ratios=(1.0, 1.25))
    ax_shape = fig.add_subplot(gs[:, 0])
    ax0 = fig.add_subplot(gs[0, 1])
    axes = [ax0, fig.add_subplot(gs[1, 1], sharex=ax0), fig.add_subplot(gs[2, 1], sharex=ax0)]
    plot_finger(sol, finger, ax=ax_shape)
    ax_shape.set_title("deformed shape (undeformed dashed)")
    plot_internal_forces(sol, axes, components=components, finger=finger)
    frame = (
        "world frame (x, z)"
        if components == "world"
        else "beam frame ($d_3$ along the beam, $d_1$ across it)"
    )
    axes[0].set_title(f"internal force n(s) and moment m(s), {frame}", fontsize="medium")
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    tip = np.asarray(sol.tip.displacement, dtype=np.float64)
    rot = np.degrees(float(np.asarray(sol.tip.rotation)[1]))
    head = f"{title}: " if title else ""
    fig.suptitle(
        f"{head}{sol.status}, load factor {float(sol.load_factor):.4g}; tip displacement "
        f"dx = {tip[0]:.3g} mm, dz = {tip[2]:.3g} mm, rotation about y = {rot:.3g} deg"
    )
    return fig


def save_solution_figure(
    sol,
    finger: Finger,
    path,
    *,
    title: str | None = None,
    dpi: int = 130,
    components: str = "material",
) -> None:
    """Save `solution_figure` to `path` (format from the extension, e.g. .png, .pdf)."""
    save_figure(solution_figure(sol, finger, title=title, components=components), path, dpi)
