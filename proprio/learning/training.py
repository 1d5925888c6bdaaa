"""Training loop of §4.4: AdamW (lr 1e-3), ReduceLROnPlateau (patience 2), up to 100 epochs, early stopping on the
validation loss, a checkpoint after every epoch and resume after an interruption.

Loss (``loss``), per joint j with σ_j the std of its training target (τ − τ_RBD for a hybrid): ``nm2`` — the mean
squared torque error in N·m² of eq. 4.38, the metric of Table 5.3 (joints with large residuals, J2 and J4, dominate
and the wrist joints are hardly learned); ``normalised`` — e_j²/σ_j² (every joint weighs the same, the large joints
suffer); or ``inv_std`` — e_j²/σ_j, in between: on 203 min of twin data it gives the lower Table 5.3 average MSE,
0.026 vs 0.032 N·m² for nm2 with LSTM-2-FCL (README, "Hybrid models on the twin"). The learning-rate scheduler and
early stopping watch the validation loss; the weights of the best validation epoch are restored at the end.

A hybrid never ends worse than its backbone on the validation split: τ_RBD alone (what
:meth:`~proprio.learning.models.HybridModel.zero_output` makes of a hybrid) is the score to beat from the start, so
when no epoch beats it the model falls back to the backbone exactly (``TrainResult.fallback`` = "all"); otherwise,
where the network has a separate output row per joint, each joint whose validation gain over the backbone is not
significant is zeroed (falls back to τ_RBD; ``fallback`` lists those joints): per validation window, the residual's
MSE minus the backbone's; the joint keeps its residual only where their mean lies below zero by more than
:data:`FALLBACK_Z` standard errors (one-sided, 95 %), so a gain of 1 % on a few windows that a later run does not
repeat is not taken for one. The validation split is a contiguous block at the end of each training recording
(:func:`~proprio.learning.datasets.make_split`): motion later in time than anything trained on, never the test
split. A warm start (``warm``: fine-tuning a pretrained model, ``proprio train --init``) keeps the
model's normalisation and scores its weights as given on the validation split too: the saved model is the best of
backbone, pretrained weights and fine-tuned epochs, the per-joint fallback still against the backbone once an epoch
has run (scored at 0 epochs, the pretrained model keeps its own per-joint decisions and falls back only whole).

The checkpoint (written atomically after each epoch) holds the model, optimizer, scheduler, epoch, best weights,
history and every RNG state (torch global, the batch-order generator, CUDA), so a resumed run continues exactly where
the interrupted one stopped and ends with the same weights as an uninterrupted run (on CPU, bit for bit).
"""
from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from proprio.progress import progress_bar

from proprio.io import atomic_path
from proprio.learning.datasets import Split, Windows
from proprio.learning.models import HybridModel, first_line
from proprio.learning.sections import section_from_dict

__all__ = ["TrainConfig", "TrainResult", "train_model", "pick_device", "insignificant_joints", "FALLBACK_Z"]

_LOSS_WEIGHT_POWER = {"nm2": 0, "inv_std": 1, "normalised": 2}
"""Per-joint weight of the squared error: 1/σ_j^power (module docstring)."""
_REL_IMPROVEMENT = 1e-4
"""A validation loss counts as better only if it is this much lower (relative) — ReduceLROnPlateau's default
threshold, so early stopping and the scheduler agree on what a plateau is."""
FALLBACK_Z = 1.645
"""A joint keeps its residual only where its validation gain over the backbone (per window, paired) lies this many
standard errors below zero: a one-sided test at 95 % (module docstring)."""


@dataclass
class TrainConfig:
    """Optimiser and schedule settings (the ``train:`` config section)."""
    lr: float = 1e-3
    weight_decay: float = 1e-2
    max_epochs: int = 100
    batch_size: int = 32            # subsequences per batch
    lr_patience: int = 2            # ReduceLROnPlateau patience [epochs]
    lr_factor: float = 0.5
    early_stop_patience: int = 15   # epochs without a better validation loss
    seed: int = 0
    device: str = "auto"            # auto | cpu | cuda
    loss: str = "nm2"               # nm2 (eq. 4.38) | normalised | inv_std

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> "TrainConfig":
        cfg = section_from_dict(cls, d, "train")
        if cfg.max_epochs < 0 or cfg.batch_size < 1:
            raise ValueError("train: max_epochs must be >= 0 (0: no epoch, the warm start or the backbone is scored "
                             "and kept) and batch_size >= 1")
        if cfg.loss not in _LOSS_WEIGHT_POWER:
            raise ValueError(f"train: loss '{cfg.loss}' must be one of {sorted(_LOSS_WEIGHT_POWER)}")
        if cfg.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"train: device '{cfg.device}' must be auto, cpu or cuda")
        return cfg


@dataclass
class TrainResult:
    history: list[dict[str, float]] = field(default_factory=list)   # per epoch: epoch, train, val, lr, seconds
    best_epoch: int = -1            # -1: no epoch beat the backbone (a hybrid), the warm start, or none ran
    stopped_early: bool = False
    backbone_val: float = float("nan")   # validation loss of τ_RBD alone (a hybrid; NaN for a standalone model)
    fallback: str | list[int] = field(default_factory=list)   # "all" or the joints (0-based) that predict τ_RBD
    init_val: float = float("nan")       # validation loss of the warm-start weights before training (NaN: cold start)

    def fallback_line(self) -> str:
        """One line saying whether and where the residual fell back to its backbone (empty for no fallback)."""
        if self.fallback == "all":
            return (f"residual not kept: no epoch beat the backbone on the validation split (loss "
                    f"{self.backbone_val:.4g}); the saved hybrid predicts τ_RBD exactly")
        if self.fallback:
            return (f"residual zeroed on joint(s) {', '.join(str(j + 1) for j in self.fallback)}: not significantly "
                    "better than the backbone on the validation split there (one-sided 95 %); those joints predict "
                    "τ_RBD exactly")
        return ""

    @property
    def seconds_per_epoch(self) -> float:
        return float(np.mean([h["seconds"] for h in self.history])) if self.history else float("nan")


def pick_device(name: str = "auto") -> torch.device:
    """CUDA when present (``auto``), else CPU."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("train: device 'cuda' requested but no CUDA device is available")
    return torch.device(name)


def _tensors(w: Windows, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    return (torch.as_tensor(w.features, dtype=torch.float32, device=device),
            torch.as_tensor(w.tau, dtype=torch.float32, device=device))


def _loss(model: HybridModel, x: torch.Tensor, tau: torch.Tensor, kind: str) -> torch.Tensor:
    err = model(x) - tau
    power = _LOSS_WEIGHT_POWER[kind]
    return ((err if power == 0 else err / model.y_std ** (0.5 * power)) ** 2).mean()


@torch.no_grad()
def _joint_mse(pred: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, tau: torch.Tensor, batch: int
               ) -> torch.Tensor:
    """Per-joint validation MSE [N·m²] of ``pred(x)`` against ``tau``."""
    sq = sum(((pred(x[i:i + batch]) - tau[i:i + batch]) ** 2).reshape(-1, tau.shape[-1]).sum(0)
             for i in range(0, len(x), batch))
    return sq / max(tau.shape[0] * tau.shape[1], 1)


@torch.no_grad()
def _window_mse(pred: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, tau: torch.Tensor, batch: int
                ) -> torch.Tensor:
    """Per-window, per-joint MSE ``[W, n]`` [N·m²] of ``pred(x)`` against ``tau``."""
    return torch.cat([((pred(x[i:i + batch]) - tau[i:i + batch]) ** 2).mean(1) for i in range(0, len(x), batch)])


def insignificant_joints(model_mse: torch.Tensor, backbone_mse: torch.Tensor, z: float = FALLBACK_Z) -> list[int]:
    """The joints (0-based) whose per-window validation MSE ``[W, n]`` does not beat the backbone's significantly:
    the paired difference's mean is not below ``−z`` standard errors (with one window: not below zero)."""
    d = (model_mse - backbone_mse).double()
    se = d.std(0) / len(d) ** 0.5 if len(d) > 1 else torch.zeros(d.shape[1], dtype=d.dtype)
    return (d.mean(0) >= -z * se).nonzero().flatten().tolist()


@torch.no_grad()
def _eval_loss(model: HybridModel, x: torch.Tensor, tau: torch.Tensor, batch: int, kind: str) -> float:
    model.eval()
    total = sum(_loss(model, x[i:i + batch], tau[i:i + batch], kind).item() * len(x[i:i + batch])
                for i in range(0, len(x), batch))
    return total / max(len(x), 1)


def _fingerprint(model: HybridModel, cfg: TrainConfig, split: Split) -> dict[str, Any]:
    return {"model": asdict(model.cfg), "train": {k: v for k, v in asdict(cfg).items() if k != "device"},
            "windows": [len(split.train), len(split.val)]}


def train_model(model: HybridModel, split: Split, cfg: TrainConfig, checkpoint: str | Path | None = None,
                progress: bool = True, on_epoch_end: Callable[[int, dict[str, float]], None] | None = None,
                warm: bool = False) -> TrainResult:
    """Set the normalisation from ``split.train`` and train ``model`` in place; returns the history.

    ``checkpoint``: file written after every epoch; if it exists (same model/train config and data size) training
    resumes from it — after the last epoch it only restores the best weights. ``on_epoch_end(epoch, record)`` is
    called after each epoch's checkpoint (tests use it to simulate a kill). ``warm``: ``model`` is already trained
    (a warm start, e.g. a pretrained residual to fine-tune): its normalisation is kept, and its weights as given are
    scored on the validation split beside the backbone, so that they are kept when no epoch beats them
    (``TrainResult.init_val``).
    """
    device = pick_device(cfg.device)
    torch.manual_seed(cfg.seed)
    if not warm:
        model.set_normalisation(split.train.features, split.train.tau)
    model.to(device=device, dtype=torch.float32)
    x_tr, y_tr = _tensors(split.train, device)
    x_va, y_va = _tensors(split.val if len(split.val) else split.train, device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, patience=cfg.lr_patience, factor=cfg.lr_factor)
    gen = torch.Generator().manual_seed(cfg.seed)
    result, start, best_val, best_state, bad = TrainResult(), 0, float("inf"), None, 0
    n, hybrid = model.cfg.n_joints, model.cfg.hybrid
    backbone = lambda xb: xb[..., :n]  # noqa: E731  # τ_RBD, the first feature block
    if hybrid:
        base = _joint_mse(backbone, x_va, y_va, 4 * cfg.batch_size)
        best_val = result.backbone_val = float((base / model.y_std ** _LOSS_WEIGHT_POWER[cfg.loss]).mean())
    if warm:
        result.init_val = _eval_loss(model, x_va, y_va, 4 * cfg.batch_size, cfg.loss)
        if result.init_val < best_val:
            best_val, best_state = result.init_val, {k: v.detach().clone() for k, v in model.state_dict().items()}
    fingerprint = _fingerprint(model, cfg, split)

    ckpt = Path(checkpoint) if checkpoint is not None else None
    if ckpt is not None and ckpt.exists():
        try:
            state = torch.load(ckpt, map_location=device, weights_only=True)
        except Exception as exc:  # noqa: BLE001 — torch raises several types (UnpicklingError, RuntimeError, EOFError)
            raise ValueError(f"{ckpt}: not a readable training checkpoint, remove it or choose another output path "
                             f"({exc})") from None
        if not isinstance(state, dict) or state.get("fingerprint") != fingerprint:
            raise ValueError(f"{ckpt}: checkpoint belongs to a different model/config/dataset; remove it or choose "
                             "another output path")
        try:
            model.load_state_dict(state["model"])
            opt.load_state_dict(state["optimizer"])
            sched.load_state_dict(state["scheduler"])
            gen.set_state(state["rng_batches"])
            torch.set_rng_state(state["rng_torch"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"{ckpt}: a damaged training checkpoint ({first_line(exc)}); remove it "
                             "or choose another output path") from None
        if device.type == "cuda" and "rng_cuda" in state:
            torch.cuda.set_rng_state(state["rng_cuda"])
        start, best_val, bad = state["epoch"] + 1, state["best_val"], state["bad_epochs"]
        best_state, result = state["best_state"], TrainResult(**state["result"])

    bar = progress_bar(range(start, cfg.max_epochs), desc=model.cfg.label(), enabled=progress, unit="epoch",
               initial=start, total=cfg.max_epochs)
    for epoch in bar:
        if result.stopped_early:
            break
        t0 = time.perf_counter()
        model.train()
        perm = torch.randperm(len(x_tr), generator=gen).to(device)
        total = 0.0
        for i in range(0, len(perm), cfg.batch_size):
            idx = perm[i:i + cfg.batch_size]
            opt.zero_grad(set_to_none=True)
            loss = _loss(model, x_tr[idx], y_tr[idx], cfg.loss)
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        val = _eval_loss(model, x_va, y_va, 4 * cfg.batch_size, cfg.loss)
        sched.step(val)
        record = {"epoch": epoch, "train": total / len(perm), "val": val, "lr": opt.param_groups[0]["lr"],
                  "seconds": time.perf_counter() - t0}
        result.history.append(record)
        if val < best_val * (1.0 - _REL_IMPROVEMENT):
            best_val, bad, result.best_epoch = val, 0, epoch
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        else:
            bad += 1
        result.stopped_early = bad >= cfg.early_stop_patience
        bar.set_postfix(train=f"{record['train']:.4f}", val=f"{val:.4f}", lr=f"{record['lr']:.0e}")
        if ckpt is not None:
            payload = {"fingerprint": fingerprint, "epoch": epoch, "model": model.state_dict(),
                       "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                       "rng_batches": gen.get_state(), "rng_torch": torch.get_rng_state(), "best_val": best_val,
                       "bad_epochs": bad, "best_state": best_state, "result": copy.deepcopy(asdict(result))}
            if device.type == "cuda":
                payload["rng_cuda"] = torch.cuda.get_rng_state()
            with atomic_path(ckpt) as tmp:
                torch.save(payload, tmp)
        if on_epoch_end is not None:
            on_epoch_end(epoch, record)
    bar.close()
    if best_state is not None:
        model.load_state_dict(best_state)
    if hybrid and best_state is None:
        model.zero_output()
        result.fallback = "all"
    elif hybrid and model.per_joint_output and not (warm and not result.history):
        # a warm start scored without an epoch keeps the pretrained model's own per-joint decisions (made on its
        # training's validation blocks): nothing was trained here for this split's few windows to decide on
        model.eval()
        worse = insignificant_joints(_window_mse(model, x_va, y_va, 4 * cfg.batch_size),
                                     _window_mse(backbone, x_va, y_va, 4 * cfg.batch_size))
        if worse:
            model.zero_output(worse)
        result.fallback = worse
    model.to("cpu").eval()
    return result
