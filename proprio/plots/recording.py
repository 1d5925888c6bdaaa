"""A recording's joint positions and torques over time."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from proprio.plots.figure import pyplot, save_figure

__all__ = ["plot_q_tau"]


def plot_q_tau(path: str | Path, t: np.ndarray, q: np.ndarray, tau: np.ndarray, joint_names: Sequence[str],
               title: str = "") -> Path:
    """Write a PNG of joint positions ``q`` [rad] and torques ``tau`` [N·m] (both ``(N, n)``) over ``t`` [s]."""
    plt = pyplot()
    fig, (ax_q, ax_t) = plt.subplots(2, 1, sharex=True, figsize=(10, 6.5), constrained_layout=True)
    for j, name in enumerate(joint_names):
        ax_q.plot(t, q[:, j], lw=1.0, label=name)
        ax_t.plot(t, tau[:, j], lw=1.0, label=name)
    ax_q.set_ylabel("q [rad]")
    ax_t.set_ylabel("τ [N·m]")
    ax_t.set_xlabel("t [s]")
    ax_q.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    for ax in (ax_q, ax_t):
        ax.grid(alpha=0.3)
    ax_q.set_title(title)
    return save_figure(fig, path)
