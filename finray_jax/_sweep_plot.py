"""The figure of a sweep (sweep.png): line plots for a 1-D sweep, heat maps for a 2-D
grid, scatter plots otherwise, drawn from the results CSV's columns."""

from __future__ import annotations

import os

import numpy as np

from ._sweep_file import Sweep


def plot_sweep(sweep: Sweep, data: dict[str, np.ndarray], path: str) -> None:
    """Line plots for a 1-D sweep, heat maps for a 2-D grid, scatter plots otherwise.
    Only converged designs are drawn (beyond-limit ones as orange crosses on line and
    scatter plots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, outs = sweep.names, sweep.outputs
    ok = data["status"] == "converged"
    beyond = data["status"] == "beyond_limit_load"
    heat = sweep.sampling == "grid" and len(names) == 2
    cols = 1 if heat or len(names) == 1 else len(names)
    fig, axs = plt.subplots(
        len(outs), cols, figsize=(4.8 * cols, 3.2 * len(outs)), squeeze=False, layout="constrained"
    )
    for i, out in enumerate(outs):
        y = data[out]
        if heat:
            a, b = sweep.axes
            z = np.where(ok, y, np.nan).reshape(a.points, b.points)
            ax = axs[i, 0]
            mesh = ax.pcolormesh(
                np.linspace(b.lo, b.hi, b.points),
                np.linspace(a.lo, a.hi, a.points),
                z,
                shading="nearest",
            )
            fig.colorbar(mesh, ax=ax, label=out)
            ax.set_xlabel(b.name)
            ax.set_ylabel(a.name)
            continue
        for j, name in enumerate(names):
            ax, x = axs[i, j], data[name]
            if sweep.sampling == "grid" and len(names) == 1:
                ax.plot(x[ok], y[ok], "-o", ms=3)
            else:
                ax.scatter(x[ok], y[ok], s=8)
            if np.any(beyond):
                ax.plot(x[beyond], y[beyond], "x", color="tab:orange", label="beyond limit load")
                ax.legend(fontsize=7)
            ax.set_xlabel(name)
            ax.set_ylabel(out)
    fig.suptitle(f"{os.path.basename(sweep.source)}: {sweep.size} designs ({sweep.sampling})")
    fig.savefig(path, dpi=120)
    plt.close(fig)
