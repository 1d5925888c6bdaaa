"""What a GPU buys for Table 5.3 at the thesis' size: ``train_model(..., device=...)`` timed on CUDA and on the CPU.

    python benchmarks/bench_gpu_table53.py [--minutes 83] [--epochs 5] [--batch 8 32 256] [--devices cuda cpu]
        [--threads 16] [--full] [--data REC.npz ... [--backbone SPEC]] [--out DIR]

Self-contained: it needs only torch, numpy, scipy, PyYAML and this repository on ``PYTHONPATH`` (no Drake, no
network), so it runs on a lent GPU machine as it is (``PYTHONPATH=. python3 benchmarks/bench_gpu_table53.py``).

The recipe is ``train_hybrid_twin``'s (LSTM-2-FCL with r on the backbone, T = 100 at 75 Hz, AdamW, its lr schedule,
early stopping and loss), read from ``proprio/configs/train_hybrid_twin.yaml``. The data, by default: thesis-shaped
synthetic recordings, ``--minutes`` of 7-joint motion at 75 Hz (83 min: the thesis' 89 min, the README's 83-min set
rfma16 + rfma40 + rfma11, cut into recordings of the same lengths, 6.1 + 16.1 + 61 min), with a residual the network
can learn (Coulomb-like friction in q̇ and a reversal term in r on a sine backbone); the split is the project's
(:func:`~proprio.learning.datasets.make_split`: a 20 % test split, validation blocks at the end of each recording).
Per epoch the work depends only on the number and shape of the windows, so s/epoch is the real set's. With
``--data`` (where Drake is installed), the real twin recordings instead, through the training's own conditioning
and backbone (``proprio.experiments.hybrid.prepare_split``).

Printed per device and batch size: s/epoch (the mean over the epochs after the first, which holds CUDA's start-up),
the first epoch, epochs run, best validation loss, and the same-run ratio CPU / CUDA. ``--full`` trains to the
recipe's early stop (≤ 400 epochs) at the recipe's batch size on the first device only: the wall time of the whole
Table 5.3 training. A model trained on CUDA is saved and loaded on the CPU and must predict the same windows (to
float32 rounding). ``--out DIR``: ``timings.json`` (and ``table53_cuda.pt`` when CUDA trained one).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import yaml

from proprio.learning.datasets import DataConfig, PreparedRecording, Split, make_split
from proprio.learning.features import feature_matrix, rotational_displacement
from proprio.learning.models import HybridModel, ModelConfig, load_model, save_model
from proprio.learning.training import TrainConfig, train_model

RECIPE = Path(__file__).resolve().parents[1] / "proprio" / "configs" / "train_hybrid_twin.yaml"
RATE = 75.0                                  # the model rate of train_hybrid_twin (≈150 Hz log, decimate 2) [Hz]
SHARES = (6.1, 16.1, 61.0)                   # minutes of rfma16, rfma40, rfma11 (README, "Hybrid models on the twin")
N = 7


def recipe() -> tuple[ModelConfig, DataConfig, TrainConfig]:
    """``train_hybrid_twin``'s model, data and train sections."""
    cfg = yaml.safe_load(RECIPE.read_text())
    model = ModelConfig.from_dict({**cfg["model"], "window": cfg["data"]["window"], "rate_hz": RATE})
    return model, DataConfig.from_dict(cfg["data"]), TrainConfig.from_dict(cfg["train"])


def synthetic_recording(minutes: float, seed: int) -> PreparedRecording:
    """``minutes`` of smooth 7-joint motion at :data:`RATE` with a learnable residual [N·m] (module docstring)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(minutes * 60 * RATE)) / RATE
    w, a, phase = rng.uniform(0.05, 0.6, (3, N)), rng.uniform(0.1, 0.5, (3, N)), rng.uniform(0, 6, (3, N))

    def series(power: int, fn) -> np.ndarray:          # Σ_k a_k w_k^power fn(w_k t + φ_k)
        return sum(a[k] * w[k] ** power * fn(np.outer(t, w[k]) + phase[k]) for k in range(3))
    q, qd, qdd = series(0, np.sin), series(1, np.cos), -series(2, np.sin)
    r = rotational_displacement(q)
    tau_rbd = 10 * np.sin(q)
    tau = tau_rbd + 0.3 * np.tanh(qd / 0.05) + 0.2 * np.tanh(r / 0.035) + rng.normal(0, 0.02, q.shape)
    return PreparedRecording(f"synthetic{seed}", t, feature_matrix(tau_rbd, q, qd, qdd, r), tau)


def synthetic_split(minutes: float, data: DataConfig) -> Split:
    recs = [synthetic_recording(minutes * s / sum(SHARES), seed) for seed, s in enumerate(SHARES)]
    return make_split(recs, data)


def twin_split(paths: list[Path], backbone: str | None, data: DataConfig) -> Split:
    """The real recordings' split through the training's own path (needs Drake)."""
    from proprio.experiments.hybrid import prepare_split, resolve_backbone
    from proprio.recording import load_recording
    recs = [load_recording(p) for p in paths]
    return prepare_split(recs, resolve_backbone(backbone or recs[0].meta["robot"]), data,
                         names=[p.stem for p in paths])


def timed(split: Split, model_cfg: ModelConfig, train: TrainConfig, device: str) -> tuple[HybridModel, dict]:
    torch.manual_seed(train.seed)
    model = HybridModel(model_cfg)
    t0 = time.perf_counter()
    result = train_model(model, split, replace(train, device=device), progress=False)
    wall = time.perf_counter() - t0
    secs = [h["seconds"] for h in result.history]
    steady = float(np.mean(secs[1:])) if len(secs) > 1 else float(secs[0])
    return model, {"device": device, "batch": train.batch_size, "epochs": len(secs), "first_epoch_s": secs[0],
                   "s_per_epoch": steady, "wall_s": wall, "best_epoch": result.best_epoch,
                   "best_val": min(h["val"] for h in result.history), "fallback": result.fallback}


def loads_on_cpu(model: HybridModel, split: Split, out: Path) -> float:
    """Save a CUDA-trained model, load it on the CPU, and return the largest difference [N·m] between its CPU
    predictions and the model's own on CUDA, on the first test windows."""
    x = torch.as_tensor(split.test.features[:64], dtype=torch.float32)
    with torch.no_grad():
        on_gpu = model.to("cuda").eval()(x.to("cuda")).cpu().numpy()
    path = save_model(model.to("cpu"), out)
    loaded, _ = load_model(path)
    with torch.no_grad():
        on_cpu = loaded(x).numpy()
    return float(np.max(np.abs(on_cpu - on_gpu)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=83.0, help="synthetic data [min] at 75 Hz (default 83)")
    ap.add_argument("--epochs", type=int, default=5, help="epochs timed per device and batch size")
    ap.add_argument("--batch", nargs="+", type=int, default=[8, 32, 256], help="batch sizes [windows]")
    ap.add_argument("--devices", nargs="+", default=["cuda", "cpu"], choices=["cuda", "cpu"])
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="torch CPU threads (default: all cores)")
    ap.add_argument("--full", action="store_true",
                    help="also train to the recipe's early stop on the first device (the whole Table 5.3 training)")
    ap.add_argument("--data", nargs="+", type=Path, default=[], metavar="REC",
                    help="twin recordings instead of synthetic data (needs Drake)")
    ap.add_argument("--backbone", default=None, help="with --data: the backbone (default: the recordings' robot)")
    ap.add_argument("--out", type=Path, default=None, help="folder for timings.json and the CUDA-trained model")
    args = ap.parse_args()
    devices = [d for d in args.devices if d == "cpu" or torch.cuda.is_available()]
    if "cuda" in args.devices and "cuda" not in devices:
        print("no CUDA device: timing the CPU only")
    torch.set_num_threads(args.threads)
    model_cfg, data, train = recipe()
    t0 = time.perf_counter()
    split = twin_split(args.data, args.backbone, data) if args.data else synthetic_split(args.minutes, data)
    prep_s = time.perf_counter() - t0
    samples = sum(p.tau.shape[0] for p in split.recordings)
    print(f"data: {'twin recordings' if args.data else 'synthetic'}, {samples} samples at {split.rate_hz:.0f} Hz "
          f"({samples / split.rate_hz / 60:.1f} min), windows train/val/test {len(split.train)}/{len(split.val)}/"
          f"{len(split.test)} of T = {data.window}; prepared in {prep_s:.1f} s")
    name = torch.cuda.get_device_name(0) if "cuda" in devices else "-"
    print(f"torch {torch.__version__}, CUDA device: {name}, CPU threads {torch.get_num_threads()}")
    rows: list[dict] = []
    print(f"{'device':>6} {'batch':>6} {'s/epoch':>9} {'1st epoch':>10} {'best val':>10}")
    for batch in args.batch:
        for device in devices:
            model, row = timed(split, model_cfg, replace(train, max_epochs=args.epochs, batch_size=batch,
                                                         early_stop_patience=args.epochs + 1), device)
            rows.append(row)
            print(f"{device:>6} {batch:>6} {row['s_per_epoch']:>9.3f} {row['first_epoch_s']:>10.3f} "
                  f"{row['best_val']:>10.5f}", flush=True)
            if device == "cuda" and batch == train.batch_size:
                with tempfile.TemporaryDirectory() as tmp:
                    diff = loads_on_cpu(model, split, Path(tmp) / "m.pt")
                print(f"       CUDA-trained model loaded on the CPU: predictions differ by at most {diff:.2e} N·m")
        by = {r["device"]: r["s_per_epoch"] for r in rows if r["batch"] == batch}
        if len(by) == 2:
            print(f"       batch {batch}: CPU / CUDA = {by['cpu'] / by['cuda']:.2f}")
    full = None
    if args.full:
        model, full = timed(split, model_cfg, train, devices[0])
        print(f"full training ({devices[0]}, batch {train.batch_size}, ≤ {train.max_epochs} epochs, early stop "
              f"{train.early_stop_patience}): {full['epochs']} epochs, best {full['best_epoch']}, "
              f"{full['wall_s']:.0f} s ({full['s_per_epoch']:.2f} s/epoch), best val {full['best_val']:.5f}")
        if args.out is not None and devices[0] == "cuda":
            args.out.mkdir(parents=True, exist_ok=True)
            save_model(model, args.out / "table53_cuda.pt", extra={"data": data.to_dict()})
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "timings.json").write_text(json.dumps({"device": name, "samples": samples, "timed": rows,
                                                           "full": full}, indent=1))


if __name__ == "__main__":
    main()
