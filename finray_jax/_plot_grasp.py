"""Figures of grasps (matplotlib): the grasped finger with its objects and adaptor, the
contact pressure along the beams (full length and zoomed on the contact), release traces
(holding force against pull distance) and the clamp-length study.

Units: mm, N. Figures are built as `matplotlib.figure.Figure` (no pyplot).
"""

from __future__ import annotations

import numpy as np

from ._plot_finger import draw_start_outlines, plot_finger, shape_legend

PRESSURE_TOL = 1e-3  # pressure below this fraction of the largest counts as no contact


def _color(i: int) -> str:
    return f"C{i}"


def grasp_caption(g) -> str:
    """The grasp's closing, actuator force and contact force, for a title."""
    c = g.contact
    return (
        f"closing {float(g.closing):.3g} mm, actuator force {float(c.actuator_force):.3g} N\n"
        f"contact force {float(c.normal_force):.3g} N (one finger)"
    )


def plot_grasp(g, ax=None, *, title: str | None = None, legend: bool = True):
    """The deformed finger of a GraspSolution with its objects (filled where they are at
    the grasp's closing, dotted where they were at closing 0) and the adaptor; the title
    (when given) gets the closing and contact force. Returns the axes."""
    finger = g.finger
    ax = plot_finger(g.solution, finger, ax=ax, loads=False, legend=False)
    # (plot_finger drew the objects where they are; add where they were at closing 0)
    draw_start_outlines(ax, finger.objects, float(g.closing) * np.asarray(g.direction, float))
    if title:
        ax.set_title(f"{title}\n{grasp_caption(g)}", fontsize="medium")
    if legend:
        shape_legend(ax)
    return ax


def held_equal(grasps) -> str:
    """What the grasps share: the closing or the actuator force ('' when neither)."""
    d = np.array([float(g.closing) for g in grasps])
    fa = np.array([float(g.contact.actuator_force) for g in grasps])
    if np.allclose(d, d[0], rtol=1e-6, atol=1e-9):
        return f"same closing, {d[0]:.3g} mm"
    if np.allclose(fa, fa[0], rtol=1e-3, atol=1e-9):
        return f"same actuator force, {fa[0]:.3g} N"
    return ""


def grasp_figure(grasps, titles):
    """Grasps side by side (shape, object, adaptor; closing and forces in each title) and
    their contact pressure along the beams: the full length and a zoom on the contact.
    Returns a matplotlib Figure."""
    from matplotlib.figure import Figure

    n = len(grasps)
    if n == 1:  # the shape on the left, the two pressure views on the right
        fig = Figure(figsize=(11, 8), layout="constrained")
        gs = fig.add_gridspec(2, 2, width_ratios=(1.0, 1.15))
        shapes = [fig.add_subplot(gs[:, 0])]
        ax_full, ax_zoom = fig.add_subplot(gs[0, 1]), fig.add_subplot(gs[1, 1])
    else:
        fig = Figure(figsize=(5.0 * n, 11), layout="constrained")
        gs = fig.add_gridspec(2, 1, height_ratios=(2.2, 1.0))
        top = gs[0].subgridspec(1, n)
        shapes = [fig.add_subplot(top[0, i]) for i in range(n)]
        bottom = gs[1].subgridspec(1, 2, width_ratios=(1.6, 1.0))
        ax_full, ax_zoom = fig.add_subplot(bottom[0, 0]), fig.add_subplot(bottom[0, 1])
    for ax, g, title in zip(shapes, grasps, titles, strict=True):
        plot_grasp(g, ax, title=title)
    if n > 1:
        _same_limits(shapes)
        same = held_equal(grasps)
        if same:
            fig.suptitle(f"{' vs '.join(titles)}: {same}")
    plot_pressure(ax_full, ax_zoom, grasps, titles)
    return fig


def _same_limits(axes) -> None:
    """One view for all shape panels (their union), so that they compare by eye."""
    for ax in axes:
        ax.apply_aspect()
        ax.set_adjustable("box")  # (from here the limits hold, the box keeps the aspect)
    xs = [ax.get_xlim() for ax in axes]
    zs = [ax.get_ylim() for ax in axes]
    lo = (min(x[0] for x in xs), min(z[0] for z in zs))
    hi = (max(x[1] for x in xs), max(z[1] for z in zs))
    for ax in axes:
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])


def _pressures(g):
    """(beam name, s, pressure) of the front beam, and of the back beam where it touches."""
    c = g.contact
    out = [("front beam", np.asarray(g.solution.front.s), np.asarray(c.pressure_front))]
    pb = np.asarray(c.pressure_back)
    if np.any(pb > 0):
        out.append(("back beam", np.asarray(g.solution.back.s), pb))
    return out


def contact_window(grasps, pad: float = 1.0):
    """The arc-length interval (mm) where any grasp's contact pressure is non-zero (above
    PRESSURE_TOL of the largest), widened by half its width or `pad`; None: no contact."""
    curves = [(s, p) for g in grasps for _, s, p in _pressures(g)]
    pmax = max((float(np.max(p)) for _, p in curves), default=0.0)
    if not pmax > 0:
        return None
    on = np.concatenate([s[p > PRESSURE_TOL * pmax] for s, p in curves])
    lo, hi = float(on.min()), float(on.max())
    margin = max(0.5 * (hi - lo), pad)
    return lo - margin, hi + margin


def plot_pressure(ax_full, ax_zoom, grasps, titles) -> None:
    """Contact pressure (N/mm) against arc length: every grasp on both axes, the full
    length on ax_full, the contact region (shaded on ax_full) on ax_zoom."""
    for i, (g, title) in enumerate(zip(grasps, titles, strict=True)):
        for name, s, p in _pressures(g):
            ls = "-" if name == "front beam" else "--"
            kw = dict(color=_color(i), ls=ls, label=f"{title}: {name}")
            ax_full.plot(s, p, lw=1.4, **kw)
            ax_zoom.plot(s, p, lw=1.4, marker=".", ms=4, **kw)
    window = contact_window(grasps)
    for ax in (ax_full, ax_zoom):
        ax.set_xlabel("arc length s from the base (mm)")
        ax.set_ylabel("contact pressure p (N/mm)")
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.axhline(0.0, color="0.5", lw=0.6)
    ax_full.set_title("contact pressure along the beams (full length)", fontsize="medium")
    if window is None:
        ax_zoom.set_title("no contact: the pressure is zero everywhere", fontsize="medium")
    else:
        ax_full.axvspan(*window, color="0.5", alpha=0.15, lw=0, label="zoomed (right)")
        ax_zoom.set_xlim(*window)
        ax_zoom.set_title("zoom on the contact (dots: solution points)", fontsize="medium")
    ax_full.legend(fontsize="x-small", loc="best")


# --------------------------------------------------------------------------------------
# Release traces
# --------------------------------------------------------------------------------------


def plot_release(ax, traces, labels, colors=None) -> None:
    """Holding force (N, all fingers) against pull distance (mm), one line per trace,
    its peak starred and an incomplete trace's last point crossed."""
    for i, (tr, label) in enumerate(zip(traces, labels, strict=True)):
        color = colors[i] if colors is not None else _color(i)
        pull, force = np.asarray(tr.pull, float), np.asarray(tr.force, float)
        peak = f"peak {tr.peak:.3g} N" if np.isfinite(tr.peak) else "no point solved"
        if tr.peak == 0:
            peak = "not held (peak 0 N)"
        ax.plot(pull, force, "-o", ms=3, lw=1.5, color=color, label=f"{label}: {peak}")
        if np.isfinite(tr.peak) and len(pull):
            ax.plot([tr.peak_pull], [tr.peak], "*", ms=13, color=color, mec="black", mew=0.6)
        if not tr.complete and len(pull):
            ax.plot(pull[-1:], force[-1:], "x", ms=9, mew=2, color=color)
    if any(not tr.complete for tr in traces):
        ax.plot([], [], "x", ms=8, mew=2, color="0.3", label="trace stopped before release")
    ax.plot([], [], "*", ms=11, color="0.6", mec="black", mew=0.6, label="peak: holding force")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_xlabel("pull distance of the object toward the tips (mm)")
    ax.set_ylabel("holding force, all fingers (N)\n(> 0: resists the pull)")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize="x-small")


def release_figure(traces, labels, *, title: str | None = None):
    """Release traces (`ReleaseTrace`) on one plot: holding force against pull distance,
    one line per trace (label). Returns a matplotlib Figure."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    plot_release(ax, traces, labels)
    ax.set_title(title or "release: the object pulled out of the grasp")
    return fig


def release_comparison_figure(
    release: dict, labels=("original", "modified"), *, friction=0.0, closing=None
):
    """A comparison's release traces (diameter -> traces, one per adaptor label): one
    panel per object diameter, holding force against pull distance. friction, closing:
    the pull's friction coefficient and the grasps' closing (mm), for the title.
    Returns a Figure."""
    from matplotlib.figure import Figure

    n = max(len(release), 1)
    fig = Figure(figsize=(max(4.6 * n, 6.5), 4.6), layout="constrained")
    axs = np.ravel(fig.subplots(1, n, sharey=True, squeeze=False))
    for ax, (d, traces) in zip(axs, release.items(), strict=False):
        plot_release(ax, list(traces), list(labels))
        ax.set_title(f"{d:g} mm object", fontsize="medium")
    for ax in axs[1:]:
        ax.set_ylabel("")
    grasped = "" if closing is None else f" at the same closing {closing:g} mm"
    fig.suptitle(
        f"Release{grasped}: the object pulled toward the finger tips\n"
        f"friction $\\mu$ = {friction:g}; holding force = the trace's peak (star)",
        fontsize="medium",
    )
    return fig


# --------------------------------------------------------------------------------------
# Clamp-length study
# --------------------------------------------------------------------------------------


def clamp_study_figure(study):
    """The study's measured force (contact or holding) against the back beam's clamp
    length, one line per object size; dotted lines mark the best clamp lengths. When the
    actuator force is held equal, a second panel shows the closing each grasp reached."""
    from matplotlib.figure import Figure

    by_force = study.actuator_force is not None and study.closing is not None
    fig = Figure(figsize=(12.5 if by_force else 7.5, 4.8), layout="constrained")
    axs = fig.subplots(1, 2 if by_force else 1, squeeze=False)[0]
    ax = axs[0]
    for d, row, best in zip(study.diameters, study.force, study.best, strict=True):
        line = ax.plot(study.clamp_lengths, row, marker="o", label=f"{d:g} mm object")[0]
        if np.isfinite(best):
            ax.axvline(best, color=line.get_color(), ls=":", lw=1.2)
    ax.plot([], [], ls=":", color="0.3", label="best clamp length")
    if study.holding_force is None:
        ax.set_ylabel("contact force, one finger (N)")
    else:
        ax.set_ylabel(f"holding force, all fingers (N), $\\mu$ = {study.friction:g}")
    if by_force:
        for d, row in zip(study.diameters, study.closing, strict=True):
            axs[1].plot(study.clamp_lengths, row, marker="o", label=f"{d:g} mm object")
        axs[1].set_ylabel("closing reached (mm)")
        axs[1].set_title("closing the actuator force gives", fontsize="medium")
    for a in axs:
        a.set_xlabel("back-beam clamp length $l_c$ (mm)")
        a.grid(True, lw=0.4, alpha=0.5)
        a.legend(fontsize="small")
    fig.suptitle(f"modified adaptor, support up to {study.support_length:g} mm, {_held(study)}")
    return fig


def _held(study) -> str:
    """What every grasp of a clamp study held equal, in words."""
    if study.actuator_force is not None:
        return f"same actuator force {study.actuator_force:g} N"
    d = np.asarray(study.closing, float) if study.closing is not None else np.array([])
    d = d[np.isfinite(d)]
    return f"same closing {d[0]:.3g} mm" if len(d) else "same closing"
