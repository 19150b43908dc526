"""The figure of a sweep (sweep.png): line plots for a 1-D sweep, heat maps for a 2-D
grid, scatter plots otherwise (with the binned median and spread when the points are
many), drawn from the results CSV's columns; every axis names its quantity and unit."""

from __future__ import annotations

import os
import re

import numpy as np

from ._sweep_file import Sweep

MANY = 2000  # above this many points a scatter plot thins its dots and adds the median
BINS = 24  # bins of the median line

# Units of design values (the rest are lengths, mm) and of outputs (see design.py).
_DESIGN_UNITS = {
    "material.E": "MPa",
    "material.nu": "-",
    "crossbeams.angle": "rad",
    "front.curvature": "1/mm",
    "back.curvature": "1/mm",
}
_OUTPUT_UNITS = (
    (r"tip\.rotation", "rad"),
    (r"tip\.(dx|dy|dz|x|z)", "mm"),
    (r"reaction\.\w+\.f[xyz]", "N"),
    (r"reaction\.\w+\.m[xyz]", "N mm"),
    (r"max_strain(\.\w+)?|load_factor", "-"),
    (r"contact\.(length|max_penetration|support_penetration)", "mm"),
    (r"contact\..*force.*|actuator_force|release\.peak", "N"),
    (r"closing|release\.peak_pull", "mm"),
    (r"release\.complete", "1: released, 0: stopped early"),
)


def quantity_label(name: str, design: bool = False) -> str:
    """An axis label: the sweep's name for the quantity and its unit, e.g.
    "tip.dx (mm)" ("-": dimensionless); the bare name where the unit is unknown (an
    output added with register_output)."""
    if design:
        unit = _DESIGN_UNITS.get(re.sub(r"\[\d+\]$", "", name), "mm")
        return f"{name} ({unit})"
    for pattern, unit in _OUTPUT_UNITS:
        if re.fullmatch(pattern, name):
            return f"{name} ({unit})"
    return name


def _binned(x, y):
    """(bin centres, 10th, 50th and 90th percentiles of y) over BINS bins of x (bins with
    fewer than 5 points left out)."""
    edges = np.linspace(np.min(x), np.max(x), BINS + 1)
    k = np.clip(np.digitize(x, edges) - 1, 0, BINS - 1)
    rows = [
        (0.5 * (edges[i] + edges[i + 1]), *np.percentile(y[k == i], (10, 50, 90)))
        for i in range(BINS)
        if np.sum(k == i) >= 5
    ]
    return np.array(rows).T if rows else None


def _scatter(ax, x, y, many: bool, legend: bool) -> None:
    """The designs as dots; with many, faint small dots, the binned median and the band
    of the middle 80 %."""
    if not many:
        ax.scatter(x, y, s=10, alpha=0.75, lw=0, label="design" if legend else None)
        return
    ax.scatter(
        x,
        y,
        s=2,
        alpha=0.12,
        lw=0,
        color="tab:blue",
        rasterized=True,
        label="design (dot)" if legend else None,
    )
    b = _binned(x, y) if len(x) else None
    if b is not None:
        ax.fill_between(
            b[0],
            b[1],
            b[3],
            color="0.3",
            alpha=0.22,
            lw=0,
            label="10-90 % of designs" if legend else None,
        )
        ax.plot(b[0], b[2], color="black", lw=1.5, label="median" if legend else None)


def _heat(fig, ax, sweep: Sweep, out: str, z) -> None:
    a, b = sweep.axes
    mesh = ax.pcolormesh(
        np.linspace(b.lo, b.hi, b.points),
        np.linspace(a.lo, a.hi, a.points),
        z.reshape(a.points, b.points),
        shading="nearest",
    )
    fig.colorbar(mesh, ax=ax, label=quantity_label(out))
    ax.set_xlabel(quantity_label(b.name, design=True))
    ax.set_ylabel(quantity_label(a.name, design=True))
    ax.set_title(f"{out} (blank: not converged)", fontsize="medium")


def plot_sweep(sweep: Sweep, data: dict[str, np.ndarray], path: str) -> None:
    """Line plots for a 1-D sweep, heat maps for a 2-D grid, scatter plots otherwise (one
    output against one design value per panel). Only converged designs are drawn
    (beyond-limit ones as red crosses on line and scatter plots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, outs = sweep.names, sweep.outputs
    ok = data["status"] == "converged"
    beyond = data["status"] == "beyond_limit_load"
    heat = sweep.sampling == "grid" and len(names) == 2
    line = sweep.sampling == "grid" and len(names) == 1
    many = int(np.sum(ok)) > MANY
    cols = 1 if heat or len(names) == 1 else len(names)
    fig, axs = plt.subplots(
        len(outs),
        cols,
        figsize=(4.8 if heat else 4.2 * cols + 0.6, 3.3 * len(outs)),
        squeeze=False,
        layout="constrained",
        sharex="col" if not heat else False,
    )
    for i, out in enumerate(outs):
        y = np.asarray(data[out], dtype=np.float64)
        if heat:
            _heat(fig, axs[i, 0], sweep, out, np.where(ok, y, np.nan))
            continue
        for j, name in enumerate(names):
            ax, x = axs[i, j], np.asarray(data[name], dtype=np.float64)
            first = i == 0 and j == 0
            if line:
                ax.plot(x[ok], y[ok], "-o", ms=3, label="converged design" if first else None)
            else:
                _scatter(ax, x[ok], y[ok], many, first)
            if np.any(beyond):
                ax.plot(
                    x[beyond],
                    y[beyond],
                    "x",
                    ms=3 if many else 6,
                    color="tab:red",
                    label="beyond limit load" if first else None,
                )
            if i == len(outs) - 1:
                ax.set_xlabel(quantity_label(name, design=True))
            if j == 0:
                ax.set_ylabel(quantity_label(out))
            ax.grid(True, lw=0.4, alpha=0.5)
    if not heat:
        axs[0, 0].legend(fontsize=7, markerscale=3 if many else 1)
    what = (
        ""
        if heat or line
        else "; each panel: an output against one design value, the others varying"
    )
    fig.suptitle(
        f"{os.path.basename(sweep.source)}: {sweep.size} designs ({sweep.sampling}), "
        f"{int(np.sum(ok))} converged{what}"
    )
    fig.savefig(path, dpi=120)
    plt.close(fig)
