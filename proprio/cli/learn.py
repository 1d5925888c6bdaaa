"""``proprio train``, ``proprio evaluate`` and ``proprio train-grid``: hybrid models (§4.2, §4.4, §5.1).

The work is done by :mod:`proprio.experiments.hybrid`; these commands only parse arguments and load Recordings.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from proprio.cli import UserError, check_output, check_recording_robot, nonnegative_int, positive_int
from proprio.cli._backend import add_backend_args, check_backend_args, clear_state
from proprio.cli.flags import add_list
from proprio.recording import Recording, load_recording

if TYPE_CHECKING:                       # (the training stack imports torch: loaded by the commands that train)
    from proprio.experiments.hybrid import TrainingConfig

__all__ = ["register"]

_BACKBONE_HELP = ("τ_RBD backbone: a built-in robot name (iiwa14_identified, iiwa14_nominal), a robot YAML/URDF/folder "
                  "(RNEA + its friction) or an identified-model .npz from identification. Default: the 'robot' in the "
                  "first Recording's meta")


def _load(paths: list[str]) -> tuple[list[Recording], list[str]]:
    recs = [load_recording(p) for p in paths]
    return recs, [Path(p).stem for p in paths]


def _backbone(spec: str | None, recs: list[Recording], paths: list[str]):
    """The ``--backbone`` (default: the first Recording's ``meta.robot``), every Recording checked to be of its
    robot (:func:`proprio.cli.check_recording_robot`)."""
    from proprio.experiments.hybrid import resolve_backbone
    spec = spec or recs[0].meta.get("robot")
    if not spec:
        raise UserError("--backbone is required: the Recording's meta names no robot")
    try:
        backbone = resolve_backbone(spec)
    except FileNotFoundError as exc:
        raise UserError(f"--backbone {spec}: {exc}") from exc
    for rec, path in zip(recs, paths):
        check_recording_robot(rec, backbone.description, path, "--backbone")
    return backbone


def _check_device(device: str | None) -> None:
    """``cuda`` without a CUDA device is a one-line error."""
    if device == "cuda":
        import torch
        if not torch.cuda.is_available():
            raise UserError("--device cuda: torch sees no CUDA device (torch.version.cuda = "
                            f"{torch.version.cuda}); install a CUDA build of torch (make cuda-torch) on a GPU machine, "
                            "or use --device auto|cpu")


def _with_device(cfg: TrainingConfig, device: str | None) -> TrainingConfig:
    """``--device`` over the config's ``train.device`` (checked by :func:`_check_device`)."""
    _check_device(device)
    return cfg if device is None else cfg.with_train(device=device)


def _train(args: argparse.Namespace) -> int:
    import torch

    from proprio.learning.evaluation import format_table
    from proprio.experiments.hybrid import load_config, prepare_split, train_from_config
    check_output(args.out, "--out", "file")
    if args.curve:
        check_output(args.curve, "--curve", "file")
    torch.set_num_threads(args.threads)
    cfg = _with_device(load_config(args.config), args.device)
    recs, names = _load(args.data)
    tests, tnames = _load(args.test_data or [])
    backbone = _backbone(args.backbone, recs + tests, args.data + (args.test_data or []))
    split = prepare_split(recs, backbone, cfg.data, tests, names + tnames)
    print("\n".join(split.conditioning))
    if args.init and not Path(args.init).is_file():
        raise UserError(f"--init {args.init}: no such model file")
    try:
        model, result, rows = train_from_config(cfg, recs, backbone, args.out, tests, names + tnames, split=split,
                                                init=args.init)
    except ValueError as exc:
        if args.init and str(exc).startswith(str(args.init)):
            raise UserError(f"--init {exc}") from exc
        raise
    print(format_table(rows))
    if result.fallback_line():
        print(result.fallback_line())
    if args.curve:
        from proprio.plots.experiments import plot_learning_curve
        print(f"learning curve: {plot_learning_curve(args.curve, result.history, result.backbone_val)}")
    trained = (f"best epoch {result.best_epoch + 1} of {len(result.history)}, {result.seconds_per_epoch:.2f} s/epoch"
               if result.history else "max_epochs 0: no epoch trained, the start as scored on validation")
    print(f"saved {args.out} ({trained})")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    import torch

    from proprio.experiments.hybrid import evaluate_saved
    torch.set_num_threads(args.threads)
    recs, names = _load(args.data)
    tests, tnames = _load(args.test_data or [])
    backbone = (_backbone(args.backbone, recs + tests, args.data + (args.test_data or [])) if args.backbone
                else None)
    _check_device(args.device)                          # cuda without a GPU: a one-line error
    print(evaluate_saved(args.model, recs, tests, backbone, names + tnames, device=args.device or "auto"))
    return 0


def _train_grid(args: argparse.Namespace) -> int:
    import torch

    from proprio.experiments.hybrid import load_config, train_grid
    check_output(args.out, "--out", "dir")
    check_backend_args(args)
    if args.search and args.backend != "ray":
        raise UserError("--search runs Ray Tune: add --backend ray")
    torch.set_num_threads(args.threads)
    cfg = _with_device(load_config(args.config), args.device)
    if args.epochs is not None:
        cfg = cfg.with_train(max_epochs=args.epochs)
    recs, names = _load(args.data)
    tests, tnames = _load(args.test_data or [])
    out = Path(args.out)
    if args.restart:
        for f in out.glob("*.pt"):
            f.unlink()
        clear_state(out / ".tasks", True)
    backbone = _backbone(args.backbone, recs + tests, args.data + (args.test_data or []))
    _, text = train_grid(cfg, recs, backbone, out, tests, names + tnames,
                         backend=args.backend, address=args.address, workers=args.workers, threads=args.threads,
                         search=args.search)
    print(text)
    print(f"wrote {Path(args.out) / 'table.txt'}, grid.json, grid.png and one .pt per model")
    return 0


def _common(p: argparse.ArgumentParser) -> None:
    add_list(p, "--data", required=True, metavar="REC",
             help="training Recordings (.npz; LWR 4+ files are converted); split 80/20 by subsequences unless "
                  "--test-data is given")
    add_list(p, "--test-data", metavar="REC", help="held-out Recordings used as the whole test split")
    p.add_argument("--backbone", metavar="SPEC", help=_BACKBONE_HELP)
    p.add_argument("--threads", type=positive_int, default=1,
                   help="torch CPU threads (default 1; per task in train-grid)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default=None,
                   help="where torch trains and evaluates: auto (CUDA when torch sees a GPU, else CPU), cpu, cuda "
                        "(an error without one); default: the config's train.device (auto)")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train", help="train one hybrid/standalone torque model (MLP-7, LSTM-2, LSTM-2-FCL, Transformer)",
        description="Train a model on Recordings with the §4.4 protocol (decimation, 80/20 split by subsequences, "
                    "AdamW + ReduceLROnPlateau, early stopping). Checkpoints after every epoch to OUT.ckpt; rerun the "
                    "same command to resume after an interruption. Prints the Table 5.3 layout.")
    p.add_argument("--config", default="train_lstm2_fcl",
                   help="YAML config path or built-in name (train_lstm2_fcl, train_lstm2, train_mlp7, "
                        "train_transformer, train_demo; default train_lstm2_fcl)")
    _common(p)
    p.add_argument("--out", required=True, metavar="MODEL", help="model file to write (.pt)")
    p.add_argument("--init", metavar="MODEL", default=None,
                   help="warm start: fine-tune this saved model (same architecture, inputs, window and rate as the "
                        "config; trained against the same backbone) instead of starting from a zero residual")
    p.add_argument("--curve", metavar="PNG", default=None,
                   help="also plot the learning curve (train/validation loss per epoch, the backbone's validation "
                        "loss as a line) to this PNG")
    p.set_defaults(func=_train)

    p = subparsers.add_parser(
        "evaluate", help="per-joint train/test MSE of a saved model (Table 5.3 layout)",
        description="Re-create the split stored in MODEL on the given Recordings and print per-joint MSE [N·m²] of "
                    "the RBD backbone, the model (windowed: fresh state per window of T) and, for MLP/LSTM, streaming "
                    "inference (state carried over each recording).")
    p.add_argument("--model", required=True, help="model file written by 'proprio train'")
    _common(p)
    p.set_defaults(func=_evaluate)

    p = subparsers.add_parser(
        "train-grid", help="reproduce the §5.1 ablation grid (Table 5.3) in one call",
        description="Train every architecture × (hybrid, with r) variant of the grid config on one split and write "
                    "OUT/table.txt (Table 5.3 layout + windowed vs streaming), grid.json, grid.png and the models. "
                    "One task per model, here (--workers processes) or on Ray (--backend ray [--address]); the weights "
                    "are the same either way on CPU. Finished models are reused and interrupted ones resume, so a "
                    "rerun continues the grid.")
    p.add_argument("--config", default="train_grid",
                   help="grid config path or built-in name (train_grid, train_grid_lwr4; default train_grid)")
    _common(p)
    p.add_argument("--epochs", type=positive_int, help="override train.max_epochs")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--search", type=nonnegative_int, default=0, metavar="N",
                   help="before training each model, a Ray Tune search of N trials over lr, weight_decay and "
                        "batch_size (the config's search: section changes the space) with ASHA early stopping; the "
                        "model is then trained with the best settings (OUT/search_<model>.json). Needs --backend ray")
    add_backend_args(p, "1 for local, os.cpu_count() for a local Ray instance")
    p.set_defaults(func=_train_grid)
