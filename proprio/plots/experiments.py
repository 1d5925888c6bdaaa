"""The experiments' summary figures: the hybrid models' error grid and the payload force errors."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from proprio.plots.figure import pyplot, save_figure

__all__ = ["plot_model_grid", "plot_payload_errors", "plot_learning_curve"]


def plot_model_grid(path: str | Path, names: Sequence[str], train_mse: np.ndarray, test_mse: np.ndarray) -> Path:
    """Horizontal bars of each model's average joint-torque MSE [N·m²] on training and test data (log scale)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 0.3 * len(names) + 1.5))
    y = np.arange(len(names))
    ax.barh(y - 0.2, train_mse, 0.4, label="train")
    ax.barh(y + 0.2, test_mse, 0.4, label="test")
    ax.set_yticks(y, list(names))
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("average joint-torque MSE [N·m²]")
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def plot_payload_errors(path: str | Path, masses: Sequence[float], rmse: Mapping[str, np.ndarray],
                        reference: str | None, title: str) -> Path:
    """Bars of the force error's RMSE [N] per axis (one panel each), per payload mass [kg] and per row of ``rmse``
    (row name → ``(n_masses, 3)``); the row named ``reference`` is drawn in grey (log scale)."""
    plt = pyplot()
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.8), sharey=True)
    width = 0.8 / len(rmse)
    x = np.arange(len(masses))
    for a, ax in enumerate(axs):
        for k, (row, vals) in enumerate(rmse.items()):
            ax.bar(x + (k - len(rmse) / 2 + 0.5) * width, vals[:, a], width, label=row,
                   color="0.6" if row == reference else f"C{k}")
        ax.set_xticks(x, [f"{int(round(m * 1000))} g" for m in masses])
        ax.set_title(f"f{'xyz'[a]}")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, axis="y")
    axs[0].set_ylabel("RMSE of the force error [N]")
    axs[-1].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_learning_curve(path: str | Path, history: Sequence[Mapping[str, float]], backbone_val: float) -> Path:
    """Training and validation loss per epoch (``history`` records with ``epoch``, ``train``, ``val``; the
    config's loss, N·m² for ``nm2``), log scale, with the backbone's (τ_RBD alone) validation loss as a dashed line
    when finite — the level a hybrid must beat to be kept."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    epochs = np.array([h["epoch"] for h in history]) + 1
    ax.plot(epochs, [h["train"] for h in history], label="train")
    ax.plot(epochs, [h["val"] for h in history], label="validation")
    if np.isfinite(backbone_val):
        ax.axhline(backbone_val, color="k", ls="--", lw=1, label="backbone alone (validation)")
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("loss")
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)
