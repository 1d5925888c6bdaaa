"""The thesis' Fig. 4.9 views of a joint trajectory: the flange path coloured by speed, and the joint angles."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from proprio.plots.figure import pyplot, save_figure

__all__ = ["plot_flange_path"]


def plot_flange_path(path: str | Path, t: np.ndarray, q: np.ndarray, p: np.ndarray, speed: np.ndarray,
                     joint_names: Sequence[str], title: str = "") -> Path:
    """Write a PNG: the flange positions ``p`` ``(N, 3)`` [m, world frame] in 3-D coloured by the flange's linear
    speed ``speed`` ``(N,)`` [m/s] (top), and the joint angles ``q`` ``(N, n)`` [rad, drawn in deg] over ``t`` [s]."""
    plt = pyplot()
    fig = plt.figure(figsize=(9, 11))
    ax = fig.add_subplot(2, 1, 1, projection="3d")
    sc = ax.scatter(p[:, 0], p[:, 1], p[:, 2], c=speed, cmap="jet", s=1.5, linewidths=0)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title or "flange path (colour: linear speed)")
    fig.colorbar(sc, ax=ax, shrink=0.7, label="flange speed [m/s]")
    ax2 = fig.add_subplot(2, 1, 2)
    for j, name in enumerate(joint_names):
        ax2.plot(t, np.degrees(q[:, j]), lw=0.7, label=name)
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("joint angle [deg]")
    ax2.legend(ncol=4, fontsize=7, loc="upper right")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)
