"""End-to-end jobs behind ``proprio train / evaluate / train-grid`` and the demo: configs, backbones, the §5.1 grid.

A training config (``proprio/configs/train_*.yaml``) has three sections, each a dataclass:
``model:`` (:class:`~proprio.learning.models.ModelConfig`), ``data:`` (:class:`~proprio.learning.datasets.DataConfig`)
and ``train:`` (:class:`~proprio.learning.training.TrainConfig`); the grid config adds ``grid:`` (architectures and
the (hybrid, use_r) variants of Table 5.3).

The τ_RBD backbone is named by a *backbone spec*: a built-in robot name, a robot YAML/URDF/folder (RNEA of the
description + its viscous/Coulomb friction), or an identified-model ``.npz`` from ``proprio identify``.
"""
from __future__ import annotations

import importlib.resources
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
import yaml

from proprio.description import RobotDescription, load_robot
from proprio.io import atomic_write_text
from proprio.learning.datasets import DataConfig, Split, make_split, prepare_recording
from proprio.learning.evaluation import (TableRow, evaluate_model, format_table, predict_streaming, predict_windowed,
                                         rbd_row, streaming_row)
from proprio.learning.features import TauRbdProvider, rbd_provider
from proprio.learning.models import ARCHS, HybridModel, ModelConfig, load_model, save_model
from proprio.learning.training import TrainConfig, TrainResult, train_model
from proprio.recording import Recording

__all__ = ["load_config", "Backbone", "resolve_backbone", "prepare_split", "train_from_config", "evaluate_saved",
           "train_grid", "demo_hybrid", "payload_table", "GRID_VARIANTS"]

GRID_VARIANTS = ((True, True), (True, False), (False, False), (False, True))   # (hybrid, use_r), Table 5.3 order


def load_config(spec: str | Path) -> dict[str, Any]:
    """A YAML config from a path or a built-in name (``train_lstm2_fcl`` → ``proprio/configs/train_lstm2_fcl.yaml``)."""
    path = Path(spec)
    if not path.exists():
        name = str(spec) if str(spec).endswith(".yaml") else f"{spec}.yaml"
        res = importlib.resources.files("proprio.configs") / name
        if not res.is_file():
            builtin = sorted(p.name for p in importlib.resources.files("proprio.configs").iterdir()
                             if p.name.startswith("train_"))
            raise FileNotFoundError(f"config '{spec}' is neither a file nor a built-in config ({', '.join(builtin)})")
        text = res.read_text()
    else:
        text = path.read_text()
    try:
        cfg = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"config {spec}: invalid YAML ({exc})") from exc
    if not isinstance(cfg, dict):
        raise ValueError(f"config {spec}: top level must be a mapping with model/data/train sections")
    unknown = sorted(set(cfg) - {"model", "data", "train", "grid"})
    if unknown:
        raise ValueError(f"config {spec}: unknown section(s) {unknown}; allowed: model, data, train, grid")
    return cfg


@dataclass
class Backbone:
    """A τ_RBD provider with its description and the spec that rebuilds it."""
    spec: str
    description: RobotDescription
    tau_rbd: TauRbdProvider


def resolve_backbone(spec: str | RobotDescription) -> Backbone:
    """Backbone from a spec (see the module docstring) or directly from a description."""
    if isinstance(spec, RobotDescription):
        return Backbone(spec.name, spec, rbd_provider(spec))
    path = Path(spec)
    if path.suffix == ".npz" and path.exists():
        from proprio.identification.model_io import load_model as load_identified
        ident = load_identified(path)
        return Backbone(str(spec), ident.description, ident.torque)
    desc = load_robot(spec)
    return Backbone(str(spec), desc, rbd_provider(desc))


def prepare_split(train_recs: Sequence[Recording], backbone: Backbone, data: DataConfig,
                  test_recs: Sequence[Recording] = (), names: Sequence[str] | None = None) -> Split:
    """Features for every Recording (at the model rate) and the §4.4 split (test = ``test_recs`` when given)."""
    names = list(names or [f"rec{i}" for i in range(len(train_recs) + len(test_recs))])
    for rec, name in zip(list(train_recs) + list(test_recs), names):
        if rec.n_joints != backbone.description.n:
            raise ValueError(f"{name}: recording has {rec.n_joints} joints, backbone '{backbone.spec}' has "
                             f"{backbone.description.n}")
    prep = [prepare_recording(r, backbone.tau_rbd, data, name) for r, name in zip(list(train_recs) + list(test_recs),
                                                                                   names)]
    return make_split(prep[:len(train_recs)], data, prep[len(train_recs):])


def _model_config(cfg: dict[str, Any], data: DataConfig, split: Split, n: int, **override: Any) -> ModelConfig:
    m = ModelConfig.from_dict({**cfg.get("model", {}), **override})
    return replace(m, n_joints=n, window=data.window, rate_hz=split.rate_hz,
                   reversal_deadband_deg=data.reversal_deadband_deg, r_max_deg=data.r_max_deg)


def train_from_config(cfg: dict[str, Any], train_recs: Sequence[Recording], backbone: Backbone, out: str | Path,
                      test_recs: Sequence[Recording] = (), names: Sequence[str] | None = None,
                      progress: bool = True, split: Split | None = None, **model_override: Any
                      ) -> tuple[HybridModel, TrainResult, list[TableRow]]:
    """Train one model as configured; save it to ``out`` (checkpoint ``out.ckpt`` beside it, resumed if present,
    removed on success). Returns the model, its history and the rows [RBD, model (windowed), model (streaming)]."""
    data = DataConfig.from_dict(cfg.get("data"))
    tcfg = TrainConfig.from_dict(cfg.get("train"))
    split = split or prepare_split(train_recs, backbone, data, test_recs, names)
    torch.manual_seed(tcfg.seed)            # the initial weights too come from the config's seed
    model = HybridModel(_model_config(cfg, data, split, backbone.description.n, **model_override))
    out = Path(out)
    ckpt = out.with_name(out.name + ".ckpt")
    result = train_model(model, split, tcfg, checkpoint=ckpt, progress=progress)
    rows = [rbd_row(split), evaluate_model(model, split)]
    if model.cfg.streamable:
        rows.append(streaming_row(model, split))
    extra = {"data": data.to_dict(), "train": cfg.get("train", {}), "backbone": backbone.spec,
             "history": result.history, "best_epoch": result.best_epoch,
             "mse": {r.name: {"train": r.train.tolist(), "test": r.test.tolist()} for r in rows}}
    save_model(model, out, extra)
    ckpt.unlink(missing_ok=True)
    return model, result, rows


def evaluate_saved(model_path: str | Path, train_recs: Sequence[Recording], test_recs: Sequence[Recording] = (),
                   backbone: Backbone | None = None, names: Sequence[str] | None = None) -> str:
    """Table 5.3 text for a saved model on Recordings, split with the data config stored in the model."""
    model, extra = load_model(model_path)
    backbone = backbone or resolve_backbone(extra["backbone"])
    data = DataConfig.from_dict(extra["data"])
    split = prepare_split(train_recs, backbone, data, test_recs, names)
    rows = [rbd_row(split), evaluate_model(model, split)]
    if model.cfg.streamable:
        rows.append(streaming_row(model, split))
    return format_table(rows)


def train_grid(cfg: dict[str, Any], train_recs: Sequence[Recording], backbone: Backbone, out_dir: str | Path,
               test_recs: Sequence[Recording] = (), names: Sequence[str] | None = None, progress: bool = True
               ) -> tuple[list[TableRow], str]:
    """The §5.1 ablation grid on one split: every ``grid.archs`` × ``grid.variants`` (hybrid, use_r) model, saved to
    ``out_dir/<arch>_<variant>.pt``; writes ``table.txt`` (Table 5.3 layout + windowed vs streaming),
    ``grid.json`` and ``grid.png``. A finished model file is reused, an interrupted one resumes from its checkpoint."""
    out_dir = Path(out_dir)
    grid = cfg.get("grid", {})
    archs = grid.get("archs", list(ARCHS))
    variants = [tuple(v) for v in grid.get("variants", GRID_VARIANTS)]
    bad = [a for a in archs if a not in ARCHS]
    if bad:
        raise ValueError(f"grid.archs: unknown architecture(s) {bad}; choose from {list(ARCHS)}")
    data = DataConfig.from_dict(cfg.get("data"))
    split = prepare_split(train_recs, backbone, data, test_recs, names)
    rows, stream_rows, timing = [rbd_row(split)], [], {}
    for arch in archs:
        for hybrid, use_r in variants:
            tag = f"{arch}_{'hybrid' if hybrid else 'standalone'}_{'r' if use_r else 'nor'}"
            path = out_dir / f"{tag}.pt"
            if path.exists():
                model, _ = load_model(path)
            else:
                t0 = time.perf_counter()
                model, result, _ = train_from_config(cfg, train_recs, backbone, path, progress=progress, split=split,
                                                     arch=arch, hybrid=hybrid, use_r=use_r)
                timing[tag] = {"seconds": time.perf_counter() - t0, "epochs": len(result.history),
                               "seconds_per_epoch": result.seconds_per_epoch}
            rows.append(evaluate_model(model, split))
            if model.cfg.streamable and model.cfg.arch != "mlp7":
                stream_rows.append((rows[-1], streaming_row(model, split)))
    text = "\n".join([
        f"Table 5.3 layout — {len(split.train)} train / {len(split.val)} val / {len(split.test)} test windows of "
        f"T = {data.window} samples at {split.rate_hz:.1f} Hz; backbone {backbone.spec}; windowed evaluation",
        format_table(rows), "",
        "Windowed (fresh state per window of T) vs streaming (state carried over the recording), average MSE [N·m²]:",
        f"{'model':<34} {'train win':>10} {'train str':>10} {'test win':>10} {'test str':>10}",
        *[f"{w.name:<34} {w.train.mean():>10.4f} {s.train.mean():>10.4f} {w.test.mean():>10.4f} {s.test.mean():>10.4f}"
          for w, s in stream_rows]])
    atomic_write_text(out_dir / "table.txt", text + "\n")
    atomic_write_text(out_dir / "grid.json", json.dumps({
        "rows": {r.name: {"train": r.train.tolist(), "test": r.test.tolist()} for r in rows},
        "streaming": {s.name: {"train": s.train.tolist(), "test": s.test.tolist()} for _, s in stream_rows},
        "timing": timing, "windows": [len(split.train), len(split.val), len(split.test)],
        "rate_hz": split.rate_hz, "backbone": backbone.spec}, indent=1))
    _plot_grid(rows, out_dir / "grid.png")
    return rows, text


def _plot_grid(rows: list[TableRow], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from proprio.io import save_figure
    fig, ax = plt.subplots(figsize=(8, 0.3 * len(rows) + 1.5))
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r.train.mean() for r in rows], 0.4, label="train")
    ax.barh(y + 0.2, [r.test.mean() for r in rows], 0.4, label="test")
    ax.set_yticks(y, [r.name for r in rows])
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("average joint-torque MSE [N·m²]")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path, dpi=120)


def demo_hybrid(train_recs: Sequence[Recording], test_recs: Sequence[Recording], robot: RobotDescription | str,
                out_dir: str | Path, epochs: int = 30, payload_recs: dict[str, Recording] | None = None,
                contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[HybridModel, str]:
    """The demo's stage: a small hybrid LSTM-2-FCL (with r, ``train_demo.yaml``) trained on ``train_recs`` for
    ``epochs`` and compared with the RBD backbone of ``robot`` on ``test_recs``; saved to ``out_dir/hybrid_lstm.pt``.
    With ``payload_recs`` (label → Recording with ``f_ext``, e.g. {"0 g": ..., "1000 g": ...}) the Table 5.4 force
    errors of RBD and hybrid are appended. Returns ``(model, text)``. Sized for < 60 s on 2 cores with a few
    minutes of data."""
    cfg = load_config("train_demo")
    cfg["train"] = {**cfg.get("train", {}), "max_epochs": int(epochs)}
    backbone = resolve_backbone(robot)
    model, _, rows = train_from_config(cfg, train_recs, backbone, Path(out_dir) / "hybrid_lstm.pt",
                                       test_recs=test_recs, progress=False)
    text = format_table(rows)
    if payload_recs:
        text += "\n\n" + payload_table({"RBD": None, model.cfg.label(): model}, backbone, payload_recs,
                                        DataConfig.from_dict(cfg.get("data")), contact_point)
    return model, text


def payload_table(models: dict[str, HybridModel | None], backbone: Backbone, recordings: dict[str, Recording],
                  data: DataConfig, contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> str:
    """Table 5.4 layout: force error of the Jacobian observer f̂ = J⁻ᵀ(τ_model − τ_J) (eq. 3.11/3.12, force-only,
    at ``contact_point`` in the flange frame) against the Recordings' true ``f_ext``.

    ``models``: name → model (None = the backbone alone, "RBD"); ``recordings``: label (e.g. "500 g") → Recording
    with ``f_ext``, prepared with ``data`` like the training data. Per model and recording: RMSE [N] and the standard
    deviation of the error [N] along x, y, z (world frame); samples flagged unreliable (near-singular J) are skipped.
    τ_model is the streaming prediction (state carried over the recording) of a model that has a streaming form
    (MLP-7, LSTMs), else the windowed one (a Transformer: consecutive windows of T, fresh state per window, as in
    :func:`evaluate_model`), marked "(windowed)".
    """
    from proprio.systems.observers import WrenchMapping, jacobian_wrench
    mapping = WrenchMapping(force_only=True, contact_point=contact_point)
    lines = [f"{'model':<28} {'payload':>8}  {'RMSE x, y, z [N]':>22}  {'std x, y, z [N]':>22}  {'samples':>7}"]
    for label, rec in recordings.items():
        if rec.f_ext is None:
            raise ValueError(f"payload_table: recording '{label}' has no f_ext (true wrench)")
        prep = prepare_recording(rec, backbone.tau_rbd, data, label)
        t_rec = rec.t - rec.t[0]                             # the conditioned grid's clock (from the first stamp)
        f_true = np.stack([np.interp(prep.t, t_rec, rec.f_ext[:, k]) for k in range(3)], axis=1)
        q = prep.features[:, prep.n_joints:2 * prep.n_joints]
        for name, model in models.items():
            if model is None:
                tau_model = prep.tau_rbd
            elif model.cfg.streamable:
                tau_model = predict_streaming(model, prep.features)
            else:
                tau_model, name = predict_windowed(model, prep.features), f"{name} (windowed)"
            wrench, _, unreliable = jacobian_wrench(backbone.description, q, prep.tau, tau_model, mapping)
            err = (wrench[:, :3] - f_true)[~unreliable]
            rmse, std = np.sqrt((err ** 2).mean(0)), err.std(0)
            fmt = lambda v: "[" + " ".join(f"{x:6.2f}" for x in v) + "]"  # noqa: E731
            lines.append(f"{name:<28} {label:>8}  {fmt(rmse):>22}  {fmt(std):>22}  {len(err):>7}")
    return "\n".join(lines)
