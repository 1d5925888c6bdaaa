"""The sim-to-real gap diagnosis' figures: where the gap lives (gap map), its spectra, and the held-out residual
before and after the added effects."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from proprio.plots.figure import pyplot, save_figure

__all__ = ["plot_gap_map", "plot_spectra", "plot_before_after"]


def plot_gap_map(path: str | Path, share: np.ndarray, columns: Sequence[tuple[str, str]], joint_names: Sequence[str],
                 title: str = "Where the torque gap lives") -> Path:
    """Heat map of the gap-map shares ``share`` ``(n_joints, n_cells)`` [fraction of the total squared error];
    ``columns`` are the cells' ``(family, label)``. A lone ``payload`` cell is left out."""
    plt = pyplot()
    fams = [f for f, _ in columns]
    keep = [c for c, f in enumerate(fams) if f != "payload" or fams.count("payload") > 1]
    data = 100 * share[:, keep]
    fig, ax = plt.subplots(figsize=(max(8.0, 0.55 * len(keep) + 2), 0.45 * len(joint_names) + 2.4))
    im = ax.imshow(data, aspect="auto", cmap="magma_r", vmin=0)
    ax.set_yticks(range(len(joint_names)), joint_names)
    ax.set_xticks(range(len(keep)), [f"{columns[c][1]}" for c in keep], rotation=60, ha="right", fontsize=8)
    for i in range(data.shape[0]):
        for k in range(data.shape[1]):
            if data[i, k] >= 0.5:
                ax.text(k, i, f"{data[i, k]:.0f}", ha="center", va="center", fontsize=7,
                        color="white" if data[i, k] > 0.6 * data.max() else "black")
    prev = None
    for k, c in enumerate(keep):
        if prev is not None and fams[c] != prev:
            ax.axvline(k - 0.5, color="k", lw=1.2)
        prev = fams[c]
    fig.colorbar(im, ax=ax, label="% of total squared error")
    ax.set_title(title + " (each family's cells add up to the joint's share)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_spectra(path: str | Path, freq: np.ndarray, psd: np.ndarray, orders: np.ndarray, order_power: np.ndarray,
                 joint_names: Sequence[str]) -> Path:
    """Welch spectrum ``psd`` ``(n_freq, n)`` [(N·m)²/Hz] over ``freq`` [Hz] and order spectrum ``order_power``
    ``(n_orders, n)`` [(N·m)²] over ``orders`` [cycles per joint revolution] of the residual per joint (log scale)."""
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4))
    for j, name in enumerate(joint_names):
        a1.semilogy(freq[1:], psd[1:, j] + 1e-16, label=name, lw=1)
        a2.semilogy(orders, order_power[:, j] + 1e-16, label=name, lw=1)
    a1.set_xlabel("frequency [Hz]")
    a1.set_ylabel("PSD of e [(N·m)²/Hz]")
    a2.set_xlabel("order [cycles per joint revolution]")
    a2.set_ylabel("amplitude² of e vs q [(N·m)²]")
    a1.set_title("Welch spectrum of the residual")
    a2.set_title("Order spectrum (e against joint angle)")
    a2.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_before_after(path: str | Path, t: np.ndarray, e: np.ndarray, e_after: np.ndarray,
                      joint_names: Sequence[str], step_names: Sequence[str], rmse: np.ndarray) -> Path:
    """Held-out residual ``e`` ``(N, n)`` [N·m] over ``t`` [s] before, and ``e_after`` after all added effects (left),
    and the held-out RMSE per step ``rmse`` ``(1 + n_steps, n)`` [N·m], the model first (right)."""
    plt = pyplot()
    n = len(joint_names)
    fig, axes = plt.subplots(n, 2, figsize=(13, 1.7 * n + 1), sharex="col", gridspec_kw={"width_ratios": [3, 1]},
                             squeeze=False)
    labels = ["model"] + list(step_names)
    for j in range(n):
        ax = axes[j, 0]
        ax.plot(t, e[:, j], lw=0.7, color="tab:red", label="before")
        ax.plot(t, e_after[:, j], lw=0.7, color="tab:blue", label="after all added effects")
        ax.set_ylabel(f"{joint_names[j]}\ne [N·m]", fontsize=7)
        rm = rmse[:, j]
        axes[j, 1].bar(range(len(rm)), rm, color=["tab:red"] + ["tab:blue"] * (len(rm) - 1))
        axes[j, 1].set_xticks(range(len(rm)), labels if j == n - 1 else [""] * len(rm), rotation=40,
                              ha="right", fontsize=7)
        axes[j, 1].set_ylabel("RMSE", fontsize=7)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[0, 0].set_title("Held-out residual τ_meas − τ_sim, before / after the added effects")
    axes[0, 1].set_title("held-out RMSE per step [N·m]", fontsize=9)
    axes[-1, 0].set_xlabel("t [s] (first held-out recording)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)
