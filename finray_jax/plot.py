"""Plots of a finger solution (matplotlib), on the public API.

plot_finger: the deformed finger in the x-z plane, the undeformed one in grey.
plot_internal_forces: n_x(s), n_z(s) and m_y(s) along the front and back beams.
solution_figure / save_solution_figure: both, in one labelled figure.

Units: mm, N, N mm. The figure helpers build a `matplotlib.figure.Figure` directly (no
pyplot, so they work on any backend); the `ax=None` paths use pyplot, switching to the Agg
backend on a Linux machine without a display.
"""

from __future__ import annotations

import os
import sys

import numpy as np

from . import ClampedBase, DistributedLoad, Finger, FreeBase, PinnedBase, PointLoad

FRONT_COLOR = "tab:blue"
BACK_COLOR = "tab:red"
CROSSBEAM_COLOR = "tab:green"
UNDEFORMED_COLOR = "0.72"
LOAD_COLOR = "black"

# The adaptor's base kinds as markers: a square holds, a triangle pins, a circle is free.
BASE_MARKERS = {ClampedBase: "s", PinnedBase: "^", FreeBase: "o"}


def _pyplot():
    if (
        sys.platform.startswith("linux")
        and "matplotlib.pyplot" not in sys.modules
        and not os.environ.get("MPLBACKEND")
        and not os.environ.get("DISPLAY")
        and not os.environ.get("WAYLAND_DISPLAY")
    ):
        import matplotlib

        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _xz(points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    return p[..., [0, 2]]


def _undeformed_lines(finger: Finger):
    fb, bb, tip = (
        np.asarray(x, dtype=np.float64) for x in (finger.front_base, finger.back_base, finger.tip)
    )
    lf, lb = np.linalg.norm(tip - fb), np.linalg.norm(tip - bb)
    cb = finger.crossbeams
    pf = fb + np.asarray(cb.front_s)[:, None] * (tip - fb) / lf
    pb = bb + np.asarray(cb.back_s)[:, None] * (tip - bb) / lb
    return [np.stack([fb, tip]), np.stack([bb, tip])] + [
        np.stack([a, b]) for a, b in zip(pf, pb, strict=True)
    ]


def _point_on(beam_sol, s) -> np.ndarray:
    ss = np.asarray(beam_sol.s, dtype=np.float64)
    p = _xz(beam_sol.position)
    return np.array([np.interp(s, ss, p[:, 0]), np.interp(s, ss, p[:, 1])])


def _beam_of(sol, beam: int):
    if beam == 0:
        return sol.front
    if beam == 1:
        return sol.back
    return sol.crossbeam(beam - 2)


def plot_finger(
    sol,
    finger: Finger,
    ax=None,
    *,
    undeformed: bool = True,
    loads: bool = True,
    legend: bool = True,
):
    """Draw the deformed finger in the x-z plane (mm) on `ax` (new axes if None).

    undeformed: also draw the undeformed finger in grey. loads: draw the load arrows.
    Returns the axes.
    """
    if ax is None:
        _, ax = _pyplot().subplots(figsize=(5, 7))
    if undeformed:
        for k, line in enumerate(_undeformed_lines(finger)):
            ax.plot(
                line[:, 0],
                line[:, 1],
                color=UNDEFORMED_COLOR,
                lw=1.2,
                ls="--",
                label="undeformed" if k == 0 else None,
                zorder=1,
            )
    for i in range(finger.n_crossbeams):
        p = _xz(sol.crossbeam(i).position)
        ax.plot(
            p[:, 0],
            p[:, 1],
            color=CROSSBEAM_COLOR,
            lw=1.6,
            label="crossbeams" if i == 0 else None,
            zorder=2,
        )
    for b, color, name in (
        (sol.front, FRONT_COLOR, "front beam"),
        (sol.back, BACK_COLOR, "back beam"),
    ):
        p = _xz(b.position)
        ax.plot(p[:, 0], p[:, 1], color=color, lw=2.4, label=name, zorder=3)
    # Bases: the adaptor.
    for base, kind in (
        (finger.front_base, finger.adaptor.front_base),
        (finger.back_base, finger.adaptor.back_base),
    ):
        x, z = np.asarray(base, dtype=np.float64)
        marker = BASE_MARKERS[type(kind)]
        ax.plot([x], [z], marker=marker, color="black", ms=8, mfc="0.3", zorder=4)
    if loads and finger.loads:
        _draw_loads(ax, sol, finger)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.grid(True, lw=0.4, alpha=0.5)
    if legend:
        ax.legend(loc="best", fontsize="small", framealpha=0.85)
    return ax


def _draw_loads(ax, sol, finger: Finger):
    fb, tip = np.asarray(finger.front_base), np.asarray(finger.tip)
    size = 0.18 * float(np.linalg.norm(tip - fb))
    forces = []
    for load in finger.loads:
        f = np.asarray(load.force if isinstance(load, PointLoad) else load.total_force)
        forces.append(np.hypot(f[0], f[2]))
    fmax = max(max(forces), 1e-300)
    for load, fmag in zip(finger.loads, forces, strict=True):
        if fmag == 0:
            continue
        beam = _beam_of(sol, load.beam)
        if isinstance(load, PointLoad):
            f = np.asarray(load.force, dtype=np.float64)[[0, 2]]
            spots = [float(load.s)]
            label = f"point load {fmag:.3g} N"
        elif isinstance(load, DistributedLoad):
            f = np.asarray(load.total_force, dtype=np.float64)[[0, 2]]
            s0, s1 = (float(x) for x in np.asarray(load.s_range))
            spots = list(np.linspace(s0, s1, 5))
            label = f"distributed load {fmag:.3g} N total"
        else:
            continue
        d = f / np.linalg.norm(f) * size * (0.5 + 0.5 * fmag / fmax)
        if isinstance(load, DistributedLoad):
            d = d * 0.6
        for s in spots:
            head = _point_on(beam, s)
            ax.annotate(
                "",
                xy=head,
                xytext=head - d,
                arrowprops=dict(arrowstyle="-|>", color=LOAD_COLOR, lw=1.3),
                zorder=5,
            )
        if len(spots) > 1:
            tails = np.array([_point_on(beam, s) - d for s in spots])
            ax.plot(tails[:, 0], tails[:, 1], color=LOAD_COLOR, lw=1.0, zorder=5)
        tails = np.array([_point_on(beam, s) - d for s in spots])
        ax.update_datalim(tails)  # keep the arrow tails inside the view
        top = tails[np.argmax(tails[:, 1])]
        ax.annotate(
            label,
            xy=top,
            xytext=(0, 6),
            textcoords="offset points",
            ha="left",
            va="bottom",
            fontsize="small",
            color=LOAD_COLOR,
        )


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
        _, axes = _pyplot().subplots(3, 1, figsize=(6, 7), sharex=True)
    axes = list(np.ravel(axes))
    if len(axes) != 3:
        raise ValueError(f"plot_internal_forces needs 3 axes, got {len(axes)}")
    if components == "world":
        labels = ("$n_x$ (N)", "$n_z$ (N)", "$m_y$ (N mm)")
    else:
        labels = (
            "axial force $n\\cdot d_3$ (N)",
            "shear force $n\\cdot d_1$ (N)",
            "bending moment $m\\cdot d_2$ (N mm)",
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
    axes[-1].set_xlabel("arc length s (mm)")
    axes[0].legend(loc="best", fontsize="small")
    return axes


def solution_figure(sol, finger: Finger, *, title: str | None = None, components: str = "world"):
    """A figure like the paper's Fig. 3 (b-e): the deformed shape (left) and n_x, n_z, m_y
    along the front and back beams (right). Returns a matplotlib Figure (no pyplot)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 7.5), layout="constrained")
    gs = fig.add_gridspec(3, 2, width_ratios=(1.0, 1.25))
    ax_shape = fig.add_subplot(gs[:, 0])
    ax0 = fig.add_subplot(gs[0, 1])
    axes = [ax0, fig.add_subplot(gs[1, 1], sharex=ax0), fig.add_subplot(gs[2, 1], sharex=ax0)]
    plot_finger(sol, finger, ax=ax_shape)
    ax_shape.set_title("shape (undeformed dashed)")
    plot_internal_forces(sol, axes, components=components, finger=finger)
    frame = "world frame" if components == "world" else "material frame"
    axes[0].set_title(f"internal force n(s) and moment m(s), {frame}")
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
    components: str = "world",
) -> None:
    """Save `solution_figure` to `path` (format from the extension, e.g. .png, .pdf)."""
    path = os.fspath(path)
    parent = os.path.dirname(path)
    if parent:
        os.makedirs(parent, exist_ok=True)
    fig = solution_figure(sol, finger, title=title, components=components)
    fig.savefig(path, dpi=dpi)


# --------------------------------------------------------------------------------------
# Grasps
# --------------------------------------------------------------------------------------


def plot_grasp(g, ax=None, *, title: str | None = None):
    """The deformed finger of a GraspSolution with its objects and the adaptor's support;
    returns the axes."""
    finger = g.finger
    ax = plot_finger(g.solution, finger, ax=ax, loads=False, legend=False)
    for obj in finger.objects:
        out = obj.outline(300)
        ax.fill(out[:, 0], out[:, 1], color="0.85", ec="0.3", lw=1.0, zorder=0)
    ad = finger.adaptor
    if ad.support_length is not None:
        bb, tip = np.asarray(finger.back_base, float), np.asarray(finger.tip, float)
        t = (tip - bb) / np.linalg.norm(tip - bb)
        n = np.array([t[1], -t[0]])  # behind the back beam
        a = bb + float(ad.back_clamp_length) * t
        b = bb + float(ad.support_length) * t
        off = 0.5 * float(finger.back.thickness) + 1.0
        ax.plot(*np.stack([a, b]).T + off * n[:, None], color="black", lw=4, label="support")
    if float(ad.back_clamp_length) > 0:
        bb, tip = np.asarray(finger.back_base, float), np.asarray(finger.tip, float)
        t = (tip - bb) / np.linalg.norm(tip - bb)
        c = bb + float(ad.back_clamp_length) * t
        ax.plot(*np.stack([bb, c]).T, color="0.2", lw=7, alpha=0.5, label="clamped")
    if title:
        ax.set_title(title)
    return ax


def grasp_figure(grasps, titles):
    """Grasps side by side (shape, object, support) and their contact pressure along the
    front beam below. Returns a matplotlib Figure."""
    from matplotlib.figure import Figure

    n = len(grasps)
    fig = Figure(figsize=(5.0 * n, 10), layout="constrained")
    gs = fig.add_gridspec(2, n, height_ratios=(2.2, 1.0))
    ax_p = fig.add_subplot(gs[1, :])
    for i, (g, title) in enumerate(zip(grasps, titles, strict=True)):
        ax = fig.add_subplot(gs[0, i])
        c = g.contact
        plot_grasp(g, ax, title=f"{title}\ncontact force {float(c.normal_force):.3g} N")
        s = np.asarray(g.solution.front.s)
        ax_p.plot(s, np.asarray(c.pressure_front), label=f"{title}: front beam")
        if np.any(np.asarray(c.pressure_back) > 0):
            ax_p.plot(
                np.asarray(g.solution.back.s),
                np.asarray(c.pressure_back),
                ls="--",
                label=f"{title}: back beam",
            )
    ax_p.set_xlabel("arc length s (mm)")
    ax_p.set_ylabel("contact pressure (N/mm)")
    ax_p.grid(True, lw=0.4, alpha=0.5)
    ax_p.legend(fontsize="small")
    return fig


def save_figure(fig, path, dpi: int = 130) -> None:
    path = os.fspath(path)
    parent = os.path.dirname(path)
    if parent:
        os.makedirs(parent, exist_ok=True)
    fig.savefig(path, dpi=dpi)


def clamp_study_figure(study):
    """The study's measured force (contact or holding) against the back beam's clamp
    length, one line per object size; dotted lines mark the best clamp lengths."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for d, row, best in zip(study.diameters, study.force, study.best, strict=True):
        line = ax.plot(study.clamp_lengths, row, marker="o", label=f"{d:g} mm object")[0]
        if np.isfinite(best):
            ax.axvline(best, color=line.get_color(), ls=":", lw=1)
    ax.set_xlabel("back-beam clamp length l_c (mm)")
    mu = "" if study.holding_force is None else f", mu = {study.friction:g}"
    ax.set_ylabel(f"{study.measure} (N{mu})")
    held = (
        "equal closing"
        if study.actuator_force is None
        else f"actuator force {study.actuator_force:g} N"
    )
    ax.set_title(f"modified adaptor, support up to {study.support_length:g} mm, {held}")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(fontsize="small")
    return fig
