"""Per-joint MSE in the layout of the thesis' Table 5.3, and windowed vs streaming inference.

* windowed (thesis style): the sequence is cut into windows of T samples and every window starts from a fresh
  (zero) state; this is exactly what the model saw in training.
* streaming (the online path of the residual System): one pass over a whole recording with the state carried
  from sample to sample, by the residual System's own law (:class:`~proprio.learning.models.StreamingStepper`).
  For MLP-7 both are identical; the Transformer has only the windowed form (torch).

Train/test MSE are computed on the samples of the split's train/test subsequences (N·m², per joint + average).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from proprio.learning.datasets import Split, Windows
from proprio.learning.models import HybridModel, StreamingStepper

__all__ = ["TableRow", "predict_windowed", "predict_streaming", "evaluate_model", "rbd_row", "streaming_row",
           "format_table"]


@dataclass
class TableRow:
    """One line of Table 5.3: per-joint MSE [N·m²] on the train and test subsequences."""
    name: str
    train: np.ndarray
    test: np.ndarray


@torch.no_grad()
def predict_windowed(model: HybridModel, features: np.ndarray, batch: int = 256) -> np.ndarray:
    """τ ``[..., T, n]`` for windows ``features [..., T, 5n]`` (or one sequence ``[N, 5n]``, cut into windows of the
    model's T, the last one shorter), a fresh state per window."""
    model.eval()
    dtype = next(model.parameters()).dtype
    if features.ndim == 2:
        T, N = model.cfg.window, features.shape[0]
        out = np.empty((N, model.cfg.n_joints))
        for i in range(0, N, T * batch):                    # full windows in batches, then the short tail
            chunk = features[i:i + T * batch]
            w = chunk.shape[0] // T
            if w:
                out[i:i + w * T] = predict_windowed(model, chunk[:w * T].reshape(w, T, -1), batch).reshape(-1,
                                                                                                        out.shape[1])
            if chunk.shape[0] > w * T:
                out[i + w * T:i + chunk.shape[0]] = predict_windowed(model, chunk[None, w * T:], batch)[0]
        return out
    device = next(model.parameters()).device               # evaluates where the model is (CPU or CUDA)
    x = torch.as_tensor(features, dtype=dtype)
    return torch.cat([model(x[i:i + batch].to(device)).cpu() for i in range(0, len(x), batch)]).double().numpy()


def predict_streaming(model: HybridModel, features: np.ndarray) -> np.ndarray:
    """τ ``[N, n]`` N·m (float64) for one sequence ``features [N, 5n]`` with the state carried over all N samples: the
    streaming law of the residual System and the online estimator (:class:`~proprio.learning.models.StreamingStepper`:
    an LSTM's compiled step looped over the samples in one call, MLP-7 vectorised), on the model's weights in float64
    whatever its dtype and device. Equals torch's :meth:`~proprio.learning.models.HybridModel.run` to rounding
    (tests)."""
    return StreamingStepper(model).run(features)[0]


def _mse(pred: np.ndarray, tau: np.ndarray) -> np.ndarray:
    return ((pred - tau) ** 2).reshape(-1, tau.shape[-1]).mean(0)


def evaluate_model(model: HybridModel, split: Split, name: str | None = None) -> TableRow:
    """Windowed per-joint MSE on the train and test subsequences (what Table 5.3 reports)."""
    return TableRow(name or model.cfg.label(), _mse(predict_windowed(model, split.train.features), split.train.tau),
                    _mse(predict_windowed(model, split.test.features), split.test.tau))


def _gather(per_rec: list[np.ndarray], w: Windows, T: int) -> np.ndarray:
    return np.stack([per_rec[k][s:s + T] for k, s in w.origin])


def streaming_row(model: HybridModel, split: Split, name: str | None = None) -> TableRow:
    """Per-joint MSE of streaming inference (one pass per recording, state carried) on the same train/test samples."""
    preds = [predict_streaming(model, p.features) for p in split.recordings]
    T = split.train.features.shape[1]
    return TableRow(name or f"{model.cfg.label()} (streaming)",
                    _mse(_gather(preds, split.train, T), split.train.tau),
                    _mse(_gather(preds, split.test, T), split.test.tau))


def rbd_row(split: Split, name: str = "RBD") -> TableRow:
    """The backbone alone: τ_RBD (first n feature columns) against the measured τ."""
    n = split.train.tau.shape[-1]
    return TableRow(name, _mse(split.train.features[..., :n], split.train.tau),
                    _mse(split.test.features[..., :n], split.test.tau))


def format_table(rows: list[TableRow], digits: int = 4) -> str:
    """Table 5.3 layout: architecture | train MSE per joint + average | test MSE per joint + average [N·m²]."""
    n = len(rows[0].train)
    name_w = max(12, *(len(r.name) for r in rows))
    cols = [f"J{j + 1}" for j in range(n)] + ["avg"]
    cw = digits + 4
    head = (f"{'Architecture':<{name_w}} | " + " ".join(f"{c:>{cw}}" for c in cols) + " | "
            + " ".join(f"{c:>{cw}}" for c in cols))
    title = f"{'':<{name_w}} | {'MSE train [N·m²]':^{len(cols) * (cw + 1) - 1}} | {'MSE test [N·m²]':^{len(cols) * (cw + 1) - 1}}"
    lines = [title, head, "-" * len(head)]
    for r in rows:
        vals = lambda a: " ".join(f"{v:>{cw}.{digits}f}" for v in [*a, a.mean()])  # noqa: E731
        lines.append(f"{r.name:<{name_w}} | {vals(r.train)} | {vals(r.test)}")
    return "\n".join(lines)
