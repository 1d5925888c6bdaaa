"""The figure plumbing of :mod:`proprio.plots`: the non-interactive pyplot, and the atomic PNG write."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from proprio.io import atomic_path

__all__ = ["pyplot", "save_figure"]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg (file-only) backend, imported on first use (it costs ≈ 2 s)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write a matplotlib figure as PNG atomically, then close it (figures are not kept open by the library)."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return path
