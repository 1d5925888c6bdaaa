"""The force estimate at the flange against the true force, per axis."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from proprio.plots.figure import pyplot, save_figure

__all__ = ["plot_force_estimates"]


def plot_force_estimates(path: str | Path, t: np.ndarray, wrench: Mapping[str, np.ndarray], f_true: np.ndarray | None,
                         gap: np.ndarray, unreliable: np.ndarray, skip_start_s: float, skip_end_s: float,
                         title: str) -> Path:
    """Write a PNG of each observer's force ``wrench[name][:, :3]`` [N, world frame] against ``f_true`` (if given)
    over ``t`` [s], per axis; samples in ``gap`` (no data) and ``unreliable`` (bool ``(N,)``) are shaded, and the
    first ``skip_start_s`` / last ``skip_end_s`` seconds greyed."""
    plt = pyplot()
    fig, axs = plt.subplots(3, 1, sharex=True, figsize=(10, 7))
    for i, ax in enumerate(axs):
        if f_true is not None:
            ax.plot(t, f_true[:, i], "k", lw=1.5, label="true")
        for k, (obs, w) in enumerate(wrench.items()):
            ax.plot(t, w[:, i], f"C{k}", lw=0.8, label=obs)
        if gap.any():
            ax.fill_between(t, 0, 1, where=gap, transform=ax.get_xaxis_transform(),
                            color="k", alpha=0.12, label="gap in the log (no data)")
        if unreliable.any():
            ax.fill_between(t, 0, 1, where=unreliable, transform=ax.get_xaxis_transform(),
                            color="r", alpha=0.15, label="unreliable")
        ax.axvspan(t[0], t[0] + skip_start_s, color="0.85", zorder=-1)
        ax.axvspan(t[-1] - skip_end_s, t[-1], color="0.85", zorder=-1)
        ax.set_ylabel(f"f{'xyz'[i]} [N]")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right", ncol=4, fontsize=8)
    axs[-1].set_xlabel("t [s]  (grey: start-up / filter edges, excluded from statistics)")
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
