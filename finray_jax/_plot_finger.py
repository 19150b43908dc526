"""The finger's shape in the x-z plane (matplotlib): beams, the adaptor (bases, clamped
lengths, support), objects and loads, with a legend naming every symbol drawn.

Units: mm, N. Used by `plot` (solve figure) and `_plot_grasp` (grasp figures).
"""

from __future__ import annotations

import os
import sys

import numpy as np

from . import ClampedBase, DistributedLoad, Finger, FreeBase, HalfPlane, PinnedBase, PointLoad

FRONT_COLOR = "tab:blue"
BACK_COLOR = "tab:red"
CROSSBEAM_COLOR = "tab:green"
UNDEFORMED_COLOR = "0.72"
LOAD_COLOR = "black"
CLAMP_COLOR = "0.2"
OBJECT_COLOR = "0.85"

# The adaptor's base kinds as markers: a square holds, a triangle pins, a circle is free.
BASE_MARKERS = {ClampedBase: "s", PinnedBase: "^", FreeBase: "o"}
BASE_NAMES = {ClampedBase: "clamped base", PinnedBase: "pinned base", FreeBase: "free base"}


def pyplot():
    """matplotlib.pyplot, switching to the Agg backend on a Linux machine without a
    display (before pyplot is first imported)."""
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


def xz(points) -> np.ndarray:
    """The x and z coordinates of 3-D points (..., 3) -> (..., 2)."""
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
    p = xz(beam_sol.position)
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
    """Draw the deformed finger in the x-z plane (mm) on `ax` (new axes if None): beams,
    the adaptor (base markers, clamped lengths, support), the finger's objects.

    undeformed: also draw the undeformed finger in grey. loads: draw the load arrows.
    legend: a legend of the symbols drawn (only those in this plot). Returns the axes.
    """
    if ax is None:
        _, ax = pyplot().subplots(figsize=(5, 7))
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
        p = xz(sol.crossbeam(i).position)
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
        p = xz(b.position)
        ax.plot(p[:, 0], p[:, 1], color=color, lw=2.4, label=name, zorder=3)
    draw_adaptor(ax, sol, finger)
    draw_objects(ax, finger.objects)
    if loads and finger.loads:
        _draw_loads(ax, sol, finger)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.grid(True, lw=0.4, alpha=0.5)
    if legend:
        shape_legend(ax)
    return ax


def shape_legend(ax) -> None:
    """The legend of a shape plot: every labelled artist, small, below the axes (where it
    covers nothing)."""
    ax.legend(
        loc="upper center",
        bbox_to_anchor=(0.5, -0.08),
        ncol=2,
        fontsize="x-small",
        frameon=False,
        handlelength=2.2,
    )


def draw_adaptor(ax, sol, finger: Finger) -> None:
    """The adaptor: a marker per base (its kind), the clamped lengths (thick grey, on the
    deformed beams: they stay rigid), and the modified adaptor's support (black bar), each
    labelled once for the legend."""
    ad = finger.adaptor
    kinds = []
    for base, kind in ((finger.front_base, ad.front_base), (finger.back_base, ad.back_base)):
        x, z = np.asarray(base, dtype=np.float64)
        ax.plot([x], [z], marker=BASE_MARKERS[type(kind)], color="black", ms=8, mfc="0.3", zorder=4)
        if type(kind) not in kinds:
            kinds.append(type(kind))
    for kind in kinds:  # (legend entries only)
        ax.plot(
            [],
            [],
            marker=BASE_MARKERS[kind],
            ls="none",
            color="black",
            mfc="0.3",
            ms=7,
            label=BASE_NAMES[kind],
        )
    clamped = False
    for beam, length in ((sol.front, ad.front_clamp_length), (sol.back, ad.back_clamp_length)):
        length = float(length)
        if length <= 0:
            continue
        s = np.asarray(beam.s, dtype=np.float64)
        inside = s <= length
        p = np.vstack([xz(beam.position)[inside], _point_on(beam, length)])
        ax.plot(
            *p.T,
            color=CLAMP_COLOR,
            lw=7,
            alpha=0.5,
            solid_capstyle="butt",
            zorder=2.5,
            label=None if clamped else f"clamped length ({length:.3g} mm, rigid)",
        )
        clamped = True
    if ad.support_length is not None:
        bb, tip = np.asarray(finger.back_base, float), np.asarray(finger.tip, float)
        t = (tip - bb) / np.linalg.norm(tip - bb)
        n = np.array([t[1], -t[0]])  # behind the back beam
        a = bb + float(ad.back_clamp_length) * t
        b = bb + float(ad.support_length) * t
        off = 0.5 * float(finger.back.thickness) + 1.0
        ax.plot(
            *np.stack([a, b]).T + off * n[:, None],
            color="black",
            lw=4,
            solid_capstyle="butt",
            label=f"rigid support (to {float(ad.support_length):.3g} mm)",
        )


def draw_objects(ax, objects) -> None:
    """The objects, filled grey (labelled once for the legend)."""
    for k, obj in enumerate(objects):
        out = obj.outline(300)
        label = "object" if k == 0 else None
        if isinstance(obj, HalfPlane):  # (a long segment: it must not set the view)
            ax.plot(*out.T, color="0.3", lw=2.0, scalex=False, scaley=False, label=label)
        else:
            ax.fill(*out.T, color=OBJECT_COLOR, ec="0.3", lw=1.0, zorder=0, label=label)


def draw_start_outlines(ax, objects, displacement) -> None:
    """Dotted outlines of the objects moved by `displacement` (x, z): where a grasp's
    objects were at closing 0."""
    shift = np.asarray(displacement, dtype=np.float64)
    if not np.any(shift):
        return
    for k, obj in enumerate(objects):
        if isinstance(obj, HalfPlane):
            continue
        out = obj.outline(300) + shift
        ax.plot(
            *out.T,
            color="0.35",
            lw=1.0,
            ls=":",
            zorder=0,
            label="object at closing 0" if k == 0 else None,
        )


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
        _draw_arrows(ax, beam, spots, d, label)


def _draw_arrows(ax, beam, spots, d, label) -> None:
    """Arrows of direction d ending on `beam` at arc lengths `spots`, labelled above."""
    for s in spots:
        head = _point_on(beam, s)
        ax.annotate(
            "",
            xy=head,
            xytext=head - d,
            arrowprops=dict(arrowstyle="-|>", color=LOAD_COLOR, lw=1.3),
            zorder=5,
        )
    tails = np.array([_point_on(beam, s) - d for s in spots])
    if len(spots) > 1:
        ax.plot(tails[:, 0], tails[:, 1], color=LOAD_COLOR, lw=1.0, zorder=5)
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


def save_figure(fig, path, dpi: int = 130) -> None:
    """Save a Figure to `path` (format from the extension), making its folder."""
    path = os.fspath(path)
    parent = os.path.dirname(path)
    if parent:
        os.makedirs(parent, exist_ok=True)
    fig.savefig(path, dpi=dpi)
