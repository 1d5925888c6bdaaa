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
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from proprio.description import RobotDescription, load_robot
from proprio.identification.model_io import load_model as load_identified
from proprio.io import atomic_write_bytes, atomic_write_text
from proprio.learning.datasets import DataConfig, Split, make_split, prepare_recording
from proprio.learning.evaluation import (TableRow, evaluate_model, format_table, predict_streaming, predict_windowed,
                                         rbd_row, streaming_row)
from proprio.learning.features import TauRbdProvider, rbd_provider
from proprio.learning.models import ARCHS, HybridModel, ModelConfig, load_model, save_model
from proprio.learning.training import TrainConfig, TrainResult, pick_device, train_model
from proprio.plots.experiments import plot_model_grid
from proprio.recording import Recording
from proprio.systems.observers import WrenchMapping, jacobian_wrench
from proprio.tasks import Shared, Task, import_ray, init_ray, run_tasks
from proprio.typed_yaml import ConfigError, check_keys, load_typed, read_yaml

__all__ = ["load_config", "training_config", "TrainingConfig", "TrainingYaml", "GridSection", "Backbone", "resolve_backbone",
           "prepare_split", "train_from_config", "warm_start_model", "evaluate_saved",
           "train_grid", "train_grid_model", "grid_tag", "search_hyperparameters", "SEARCH_SPACE", "demo_hybrid",
           "payload_table", "GRID_VARIANTS"]

GRID_VARIANTS = ((True, True), (True, False), (False, False), (False, True))   # (hybrid, use_r), Table 5.3 order


def load_config(spec: str | Path) -> "TrainingConfig":
    """A training config from a YAML path or a built-in name (``train_lstm2_fcl`` →
    ``proprio/configs/train_lstm2_fcl.yaml``), loaded strictly into a :class:`TrainingConfig`."""
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
    source = str(spec)
    cfg = read_yaml(text=text, source=source) or {}
    if not isinstance(cfg, dict):
        raise ConfigError(f"{source}: top level must be a mapping with model/data/train sections")
    return training_config(cfg, source)


@dataclass(frozen=True)
class GridSection:
    """The ``grid:`` section of a training config: the ``archs`` and the ``[hybrid, use_r]`` ``variants`` trained
    by ``train-grid``."""
    archs: tuple[str, ...] = tuple(ARCHS)
    variants: tuple[tuple[bool, bool], ...] = GRID_VARIANTS


@dataclass(frozen=True)
class TrainingYaml:
    """The schema of a ``train_*.yaml``: ``model`` (:class:`~proprio.learning.models.ModelConfig`), ``data``
    (:class:`~proprio.learning.datasets.DataConfig`), ``train`` (:class:`~proprio.learning.training.TrainConfig`),
    ``grid`` (:class:`GridSection`) and ``search`` (``train:`` key → ``[kind, ...]``, see :data:`SEARCH_SPACE`)."""
    model: dict[str, Any] | None = None
    data: dict[str, Any] | None = None
    train: dict[str, Any] | None = None
    grid: GridSection | None = None
    search: dict[str, list[Any]] | None = None


@dataclass(frozen=True)
class TrainingConfig:
    """A loaded training config (:func:`load_config`), what the training jobs take: each section in its checked
    dataclass — ``model`` (:class:`~proprio.learning.models.ModelConfig`), ``data``
    (:class:`~proprio.learning.datasets.DataConfig`), ``train`` (:class:`~proprio.learning.training.TrainConfig`),
    ``grid`` (:class:`GridSection`) — and ``search`` (``train:`` key → ``[kind, ...]``, see :data:`SEARCH_SPACE`)."""
    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    grid: GridSection = GridSection()
    search: dict[str, list[Any]] = field(default_factory=dict)

    def with_train(self, **changes: Any) -> "TrainingConfig":
        """A copy with these ``train:`` settings changed, checked as the section is when loaded."""
        return replace(self, train=TrainConfig.from_dict({**asdict(self.train), **changes}))


def training_config(cfg: dict[str, Any], source: str) -> TrainingConfig:
    """A training-config mapping loaded strictly (:mod:`proprio.typed_yaml`): each section into its dataclass,
    with its checks; an unknown key is an error naming ``source``, the key path and the nearest valid key."""
    spec = load_typed(TrainingYaml, cfg, source)
    try:
        sections = {"model": ModelConfig.from_dict(spec.model or {}), "data": DataConfig.from_dict(spec.data),
                    "train": TrainConfig.from_dict(spec.train)}
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from exc
    check_keys(spec.search or {}, [f.name for f in fields(TrainConfig)], f"{source}: search")
    grid = spec.grid or GridSection()
    bad = [a for a in grid.archs if a not in ARCHS]
    if bad:
        raise ConfigError(f"{source}: grid.archs: unknown {bad}; choose from {list(ARCHS)}")
    return TrainingConfig(**sections, grid=grid, search=dict(spec.search or {}))


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


def _model_config(cfg: TrainingConfig, split: Split, n: int, **override: Any) -> ModelConfig:
    data = cfg.data
    m = ModelConfig.from_dict({**asdict(cfg.model), **override}) if override else cfg.model
    return replace(m, n_joints=n, window=data.window, rate_hz=split.rate_hz,
                   reversal_deadband_deg=data.reversal_deadband_deg, r_max_deg=data.r_max_deg)


def warm_start_model(path: str | Path, model_cfg: ModelConfig) -> HybridModel:
    """The model saved at ``path`` (a pretrained residual) as the start of a training run configured as
    ``model_cfg``: same architecture, inputs, sizes and window, and a model rate within 1 %; else a ValueError that
    names the file and the settings that differ. Its weights and normalisation are kept (``train_model(warm=True)``).
    Its backbone is not checked: the residual fits only the backbone it was trained against."""
    model, _ = load_model(path)
    have, want = asdict(model.cfg), asdict(model_cfg)
    differ = [k for k in want if k != "rate_hz" and have.get(k) != want[k]]
    if abs(model.cfg.rate_hz / model_cfg.rate_hz - 1.0) > 0.01:
        differ.append("rate_hz")
    if differ:
        raise ValueError(f"{path}: cannot warm-start from this model, it differs from the config in "
                         + ", ".join(f"{k} ({have.get(k)} vs {want[k]})" for k in differ))
    return model


def train_from_config(cfg: TrainingConfig, train_recs: Sequence[Recording], backbone: Backbone, out: str | Path,
                      test_recs: Sequence[Recording] = (), names: Sequence[str] | None = None,
                      progress: bool = True, split: Split | None = None, init: str | Path | None = None,
                      **model_override: Any) -> tuple[HybridModel, TrainResult, list[TableRow]]:
    """Train one model as configured; save it to ``out`` (checkpoint ``out.ckpt`` beside it, resumed if present,
    removed on success). ``init``: a saved model to start from (:func:`warm_start_model`; its weights and
    normalisation are fine-tuned, and kept where no epoch beats them) instead of the zero-start residual. Returns the
    model, its history and the rows [RBD, model (windowed), model (streaming)]."""
    data, tcfg = cfg.data, cfg.train
    split = split or prepare_split(train_recs, backbone, data, test_recs, names)
    torch.manual_seed(tcfg.seed)            # the initial weights too come from the config's seed
    model_cfg = _model_config(cfg, split, backbone.description.n, **model_override)
    model = HybridModel(model_cfg) if init is None else warm_start_model(init, model_cfg)
    out = Path(out)
    ckpt = out.with_name(out.name + ".ckpt")
    result = train_model(model, split, tcfg, checkpoint=ckpt, progress=progress, warm=init is not None)
    rows = [rbd_row(split), evaluate_model(model, split)]
    if model.cfg.streamable:
        rows.append(streaming_row(model, split))
    extra = {"data": data.to_dict(), "train": asdict(tcfg), "backbone": backbone.spec,
             "history": result.history, "best_epoch": result.best_epoch,
             "backbone_val": result.backbone_val, "fallback": result.fallback,
             "init": None if init is None else str(init), "init_val": result.init_val,
             "mse": {r.name: {"train": r.train.tolist(), "test": r.test.tolist()} for r in rows}}
    save_model(model, out, extra)
    ckpt.unlink(missing_ok=True)
    return model, result, rows


def evaluate_saved(model_path: str | Path, train_recs: Sequence[Recording], test_recs: Sequence[Recording] = (),
                   backbone: Backbone | None = None, names: Sequence[str] | None = None, device: str = "auto") -> str:
    """Table 5.3 text for a saved model on Recordings, split with the data config stored in the model; the network
    runs on ``device`` (auto | cpu | cuda, :func:`~proprio.learning.training.pick_device`)."""
    model, extra = load_model(model_path)
    model.to(pick_device(device))
    backbone = backbone or resolve_backbone(extra["backbone"])
    data = DataConfig.from_dict(extra["data"])
    split = prepare_split(train_recs, backbone, data, test_recs, names)
    rows = [rbd_row(split), evaluate_model(model, split)]
    if model.cfg.streamable:
        rows.append(streaming_row(model, split))
    return format_table(rows)


def grid_tag(arch: str, hybrid: bool, use_r: bool) -> str:
    """File stem of one grid model, e.g. ``lstm2_fcl_hybrid_r``."""
    return f"{arch}_{'hybrid' if hybrid else 'standalone'}_{'r' if use_r else 'nor'}"


def train_grid_model(cfg: TrainingConfig, split: Split, backbone_spec: str, description: RobotDescription,
                     arch: str, hybrid: bool, use_r: bool, threads: int = 1, out: str | None = None
                     ) -> dict[str, Any]:
    """One grid task: train ``arch`` × (hybrid, use_r) on the prepared ``split`` with ``threads`` torch threads and
    return ``{"model": the saved .pt as bytes, "seconds", "epochs", "seconds_per_epoch"}``. ``out``: train straight
    into that file (its checkpoint resumes an interrupted model; a local backend) — else into a temporary folder of
    the worker (a Ray worker need not see the driver's disk)."""
    import tempfile

    torch.set_num_threads(int(threads))
    backbone = Backbone(backbone_spec, description, None)   # type: ignore[arg-type]  # τ_RBD is in the split
    with tempfile.TemporaryDirectory(prefix="proprio-grid-") as tmp:
        path = Path(out) if out else Path(tmp) / f"{grid_tag(arch, hybrid, use_r)}.pt"
        t0 = time.perf_counter()
        _, result, _ = train_from_config(cfg, [], backbone, path, progress=False, split=split, arch=arch,
                                         hybrid=hybrid, use_r=use_r)
        return {"model": path.read_bytes(), "seconds": time.perf_counter() - t0, "epochs": len(result.history),
                "seconds_per_epoch": result.seconds_per_epoch}


def train_grid(cfg: TrainingConfig, train_recs: Sequence[Recording], backbone: Backbone, out_dir: str | Path,
               test_recs: Sequence[Recording] = (), names: Sequence[str] | None = None, progress: bool = True,
               backend: str = "local", address: str | None = None, workers: int | None = None, threads: int = 1,
               search: int = 0) -> tuple[list[TableRow], str]:
    """The §5.1 ablation grid on one split: every ``grid.archs`` × ``grid.variants`` (hybrid, use_r) model, saved to
    ``out_dir/<arch>_<variant>.pt``; writes ``table.txt`` (Table 5.3 layout + windowed vs streaming),
    ``grid.json`` and ``grid.png``.

    One task per model through :func:`proprio.tasks.run_tasks` (``backend`` local: ``workers`` processes, default 1;
    ray: a local Ray instance or the cluster at ``address``), each with ``threads`` torch threads and the config's
    seed, so the weights do not depend on the backend or the worker count (on CPU). The split is prepared once here
    and shipped to the tasks by value. A finished model file is reused (a rerun trains only what is missing), an
    interrupted one resumes from its checkpoint on the local backend; a failed model is reported with its config
    and left out of the table. ``search`` > 0: first a Ray Tune search of that many trials per model
    (:func:`search_hyperparameters`, ASHA early stopping), whose best ``train:`` settings the model is then trained
    with (``search_<tag>.json``)."""
    out_dir = Path(out_dir)
    archs, variants = list(cfg.grid.archs), list(cfg.grid.variants)
    bad = [a for a in archs if a not in ARCHS]
    if bad:
        raise ValueError(f"grid.archs: unknown architecture(s) {bad}; choose from {list(ARCHS)}")
    data = cfg.data
    split = prepare_split(train_recs, backbone, data, test_recs, names)
    tasks, reused = [], []
    ray_started = False
    if search > 0 and backend == "ray":           # one Ray instance for the searches and the grid
        if not import_ray().is_initialized():
            init_ray(address, workers)
            ray_started = True
    try:
        return _train_grid_tasks(cfg, archs, variants, data, split, backbone, out_dir, tasks, reused, backend,
                                 address, workers, threads, search, progress)
    finally:
        if ray_started:
            import_ray().shutdown()


def _train_grid_tasks(cfg: TrainingConfig, archs: list[str], variants: list[tuple], data: DataConfig, split: Split,
                      backbone: Backbone, out_dir: Path, tasks: list, reused: list[str], backend: str,
                      address: str | None, workers: int | None, threads: int, search: int, progress: bool
                      ) -> tuple[list[TableRow], str]:
    import sys

    tcfg = cfg.train
    shared_split = Shared(split)
    gpus: float | str = 1.0 if tcfg.device == "cuda" else ("auto" if tcfg.device == "auto" else 0.0)
    for arch in archs:
        for hybrid, use_r in variants:
            tag = grid_tag(arch, hybrid, use_r)
            path = out_dir / f"{tag}.pt"
            if path.exists():
                reused.append(tag)
                continue
            model_cfg = cfg
            if search > 0:
                best = search_hyperparameters(cfg, split, backbone, arch, hybrid, use_r, search, out_dir,
                                              address=address, workers=workers, threads=threads)
                model_cfg = cfg.with_train(**best)
            tasks.append(Task(tag, train_grid_model,
                              {"cfg": model_cfg, "split": shared_split, "backbone_spec": backbone.spec,
                               "description": backbone.description, "arch": arch, "hybrid": hybrid, "use_r": use_r,
                               "threads": threads, "out": str(path) if backend == "local" else None},
                              {"model": tag, "arch": arch, "hybrid": hybrid, "use_r": use_r,
                               "train": asdict(model_cfg.train), "model_config": asdict(model_cfg.model),
                               "data": data.to_dict(), "backbone": backbone.spec, "threads": threads},
                              num_gpus=gpus))

    def store(task: Task, result: dict[str, Any]) -> dict[str, Any]:
        atomic_write_bytes(out_dir / f"{task.key}.pt", result["model"])
        return {k: v for k, v in result.items() if k != "model"}

    run = run_tasks(tasks, out_dir / ".tasks", store, backend=backend, address=address, workers=workers,
                    progress=progress, desc="train-grid", kept=lambda task, rec: (out_dir / f"{task.key}.pt").exists())
    for f in run.failures:
        print(f.line(), file=sys.stderr)
    rows, stream_rows = [rbd_row(split)], []
    timing = dict(run.records)
    for arch in archs:
        for hybrid, use_r in variants:
            path = out_dir / f"{grid_tag(arch, hybrid, use_r)}.pt"
            if not path.exists():
                continue                                  # failed: reported above
            model, _ = load_model(path)
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
          for w, s in stream_rows],
        *(["", run.summary()] if run.failures else [])])
    atomic_write_text(out_dir / "table.txt", text + "\n")
    atomic_write_text(out_dir / "grid.json", json.dumps({
        "rows": {r.name: {"train": r.train.tolist(), "test": r.test.tolist()} for r in rows},
        "streaming": {s.name: {"train": s.train.tolist(), "test": s.test.tolist()} for _, s in stream_rows},
        "timing": timing, "windows": [len(split.train), len(split.val), len(split.test)],
        "rate_hz": split.rate_hz, "backbone": backbone.spec,
        "tasks": {"trained": run.executed, "reused": reused + run.skipped, "backend": run.backend,
                  "failed": [{"model": f.key, "config": f.config, "error": f.error} for f in run.failures]}},
        indent=1))
    plot_model_grid(out_dir / "grid.png", [r.name for r in rows], np.array([r.train.mean() for r in rows]),
                    np.array([r.test.mean() for r in rows]))
    return rows, text


SEARCH_SPACE = {"lr": ("loguniform", 1e-4, 3e-3), "weight_decay": ("loguniform", 1e-4, 1e-1),
                "batch_size": ("choice", [8, 16, 32])}
"""Default hyper-parameter space of ``train-grid --search`` (``train:`` keys); a config's ``search:`` section
replaces entries, e.g. ``search: {lr: [loguniform, 1.0e-4, 1.0e-2]}``."""


def _tune_trial(config: dict[str, Any], cfg: TrainingConfig, split: Split, description: RobotDescription,
                arch: str, hybrid: bool, use_r: bool, threads: int) -> None:
    from ray import tune

    torch.set_num_threads(int(threads))
    c = cfg.with_train(**config)
    tcfg = c.train
    torch.manual_seed(tcfg.seed)
    model = HybridModel(_model_config(c, split, description.n, arch=arch, hybrid=hybrid, use_r=use_r))
    train_model(model, split, tcfg, progress=False,
                on_epoch_end=lambda epoch, rec: tune.report({"val": rec["val"], "train": rec["train"]}))


def search_hyperparameters(cfg: TrainingConfig, split: Split, backbone: Backbone, arch: str, hybrid: bool,
                           use_r: bool, num_samples: int, out_dir: str | Path, address: str | None = None,
                           workers: int | None = None, threads: int = 1) -> dict[str, Any]:
    """Ray Tune search of ``num_samples`` trials over :data:`SEARCH_SPACE` (drawn with the config's ``train.seed``)
    for one grid model, each trial one CPU, the validation loss reported every epoch and bad trials stopped early by
    ASHA (grace period 2 epochs, halving). Writes ``out_dir/search_<tag>.json`` (every trial, the best) and returns
    the best ``train:`` settings. Uses the running Ray, else starts one (``address`` / ``workers`` CPUs)."""
    ray = import_ray()
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search import BasicVariantGenerator

    tag = grid_tag(arch, hybrid, use_r)
    tcfg = cfg.train
    space_def = {**SEARCH_SPACE, **cfg.search}
    space: dict[str, Any] = {}
    for key, spec in space_def.items():
        kind, *args = spec
        if kind == "loguniform":
            space[key] = tune.loguniform(float(args[0]), float(args[1]))
        elif kind == "uniform":
            space[key] = tune.uniform(float(args[0]), float(args[1]))
        elif kind == "choice":
            space[key] = tune.choice(list(args[0]))
        else:
            raise ValueError(f"search.{key}: unknown kind {kind!r} (loguniform, uniform, choice)")
    started = not ray.is_initialized()
    if started:
        init_ray(address, workers)
    try:
        trainable = tune.with_resources(
            tune.with_parameters(_tune_trial, cfg=cfg, split=split, description=backbone.description, arch=arch,
                                 hybrid=hybrid, use_r=use_r, threads=threads), {"cpu": 1})
        asha = ASHAScheduler(time_attr="training_iteration", max_t=tcfg.max_epochs,
                             grace_period=min(2, tcfg.max_epochs), reduction_factor=2)
        tuner = tune.Tuner(trainable, param_space=space,
                           tune_config=tune.TuneConfig(metric="val", mode="min", num_samples=int(num_samples),
                                                       scheduler=asha,
                                                       search_alg=BasicVariantGenerator(random_state=tcfg.seed)),
                           run_config=tune.RunConfig(name=f"search_{tag}",
                                                     storage_path=str((Path(out_dir) / "tune").resolve()),
                                                     verbose=0))
        results = tuner.fit()
        errors = [r.error for r in results if r.error]
        if len(errors) == len(results):
            first = str(errors[0]).strip().splitlines()[-1] if errors else "no trial ran"
            raise ValueError(f"--search: all {len(results)} trial(s) of {tag} failed; the last line of the first "
                             f"error: {first}")
        best = results.get_best_result(metric="val", mode="min", scope="all")
        trials = [{"config": r.config, "val": (r.metrics or {}).get("val"),
                   "epochs": (r.metrics or {}).get("training_iteration"),
                   "error": str(r.error) if r.error else None} for r in results]
    finally:
        if started:
            ray.shutdown()
    best_cfg = {k: (int(v) if isinstance(v, (int, np.integer)) else float(v)) for k, v in best.config.items()}
    atomic_write_text(Path(out_dir) / f"search_{tag}.json", json.dumps(
        {"model": tag, "space": {k: list(v) for k, v in space_def.items()}, "best": best_cfg,
         "best_val": best.metrics.get("val"), "trials": trials}, indent=1, default=str))
    return best_cfg


def demo_hybrid(train_recs: Sequence[Recording], test_recs: Sequence[Recording], robot: RobotDescription | str,
                out_dir: str | Path, epochs: int = 30, payload_recs: dict[str, Recording] | None = None,
                contact_point: tuple[float, float, float] = (0.0, 0.0, 0.0), init: str | Path | None = None
                ) -> tuple[HybridModel, str]:
    """The demo's stage: a small hybrid LSTM-2-FCL (with r, ``train_demo.yaml``) trained on ``train_recs`` for
    ``epochs`` — from ``init`` (a pretrained residual, :func:`warm_start_model`) when given, else from a zero
    residual — and compared with the RBD backbone of ``robot`` on ``test_recs``; saved to ``out_dir/hybrid_lstm.pt``.
    The text ends with the hybrid's average test MSE as a fraction of the RBD's. With ``payload_recs`` (label →
    Recording with ``f_ext``, e.g. {"0 g": ..., "1000 g": ...}) the Table 5.4 force errors of RBD and hybrid are
    appended. Returns ``(model, text)``. Sized for < 60 s on 2 cores with a few minutes of data."""
    cfg = load_config("train_demo").with_train(max_epochs=int(epochs))
    backbone = resolve_backbone(robot)
    model, result, rows = train_from_config(cfg, train_recs, backbone, Path(out_dir) / "hybrid_lstm.pt",
                                            test_recs=test_recs, progress=False, init=init)
    rbd = rows[0].test.mean()
    ratio = (f"test MSE hybrid / RBD: {rows[1].test.mean():.4f} / {rbd:.4f} N·m² = {rows[1].test.mean() / rbd:.2f}"
             + (f" (streaming {rows[2].test.mean() / rbd:.2f})" if len(rows) > 2 else ""))
    text = "\n".join([format_table(rows), *filter(None, [result.fallback_line()]), ratio])
    if payload_recs:
        text += "\n\n" + payload_table({"RBD": None, model.cfg.label(): model}, backbone, payload_recs,
                                        cfg.data, contact_point)
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
