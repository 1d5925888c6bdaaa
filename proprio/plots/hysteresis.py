"""The thesis' Fig. 2.5 experiment: measured joint torque against joint angle, one panel per joint."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from proprio.plots.figure import pyplot, save_figure

__all__ = ["plot_hysteresis_loops"]


def plot_hysteresis_loops(path: str | Path, loops: Sequence[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
                          title: str) -> Path:
    """Write a PNG with one panel per ``(joint index, angle [deg], τ [N·m], smoothed τ [N·m])`` in ``loops``:
    the raw torque against the angle in grey, its smoothed version on top (at most 7 panels, 2 × 4 grid)."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.5))
    for (j, ang, tau, smooth), ax in zip(loops, axes.ravel()):
        ax.plot(ang, tau, lw=0.4, color="0.6", label="measured τ_J")
        ax.plot(ang, smooth, lw=1.6, color="C3", label="Savitzky–Golay")
        ax.set_title(f"joint {j + 1}")
        ax.set_xlabel("angle [°]")
        ax.set_ylabel("τ [N·m]")
    for ax in axes.ravel()[len(loops):]:
        ax.axis("off")
    axes.ravel()[0].legend(loc="best", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
