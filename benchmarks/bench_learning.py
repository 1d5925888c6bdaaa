"""Learning-stack benchmarks: CPU training time per epoch for each architecture, and µs per sample of the streaming
hybrid estimator in a Drake Diagram.

    .venv/bin/python benchmarks/bench_learning.py [--samples 20000] [--epochs 2] [--steps 3000] [--log-minutes 10]
                                                  [--batch-only] [--trained M.pt ...]

1. Training: synthetic 7-joint data at 75 Hz (``--samples`` samples, windows of T = 100; Transformer also T = 500),
   one torch thread, batch 32 windows; prints s/epoch and training samples/s per architecture (thesis sizes:
   MLP-7 35-100-1 ×7, LSTM-2 35→35→7, LSTM-2-FCL, Transformer d=32, 4 heads, 2 layers).
2. Streaming estimator (the online path, one sample per step at the model rate):
   replay [q, q̇, q̈, τ_J] → Drake ``InverseDynamics`` (C++, τ_RBD incl. gravity) → :class:`ResidualNetworkSystem`
   (hybrid LSTM-2-FCL, float64) → :class:`JacobianWrenchObserver` + :class:`WrenchMap` (f̂ = J⁻ᵀ(τ_HYB − τ_J)) →
   logger. Prints µs per
   sample for the full Diagram and for the replay + residual System alone. Target: ≤ 100 µs per sample on one core.
   Also: the estimation diagram ``proprio estimate`` builds for a hybrid ``.pt`` (C++ backbone, residual, Jacobian
   AND momentum observer, one logger), for reference; ``bench_online.py`` times it per configuration.
3. Batch inference over one long log (``--log-minutes`` 10 at 75 Hz and at 1 kHz, float64, one thread): the training
   form (torch ``HybridModel.run``) against the inference law every path outside training calls
   (:func:`~proprio.learning.evaluation.predict_streaming` = ``StreamingStepper.run``: an LSTM's streaming kernel
   looped over the samples in one numba call, MLP-7 vectorised) — samples/s, the same-run ratio and the largest
   difference [N·m]. ``--batch-only`` runs this part alone.
4. ``--trained M.pt ...``: models saved by ``proprio train`` (their training history): epochs run, s/epoch, the time
   to the saved (best) epoch — the time it took to reach the test figure printed beside it (the Table 5.3 cell the
   run made) — on the threads it was trained with.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from pydrake.systems.analysis import Simulator
from pydrake.systems.controllers import InverseDynamics
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, LogVectorOutput, Multiplexer, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from proprio.description import load_robot
from proprio.diagrams.estimation import RigidBodyTorqueModel, build_estimation_diagram
from proprio.diagrams.hybrid_torque_model import HybridTorqueModel
from proprio.learning.datasets import DataConfig, PreparedRecording, make_split
from proprio.learning.evaluation import predict_streaming
from proprio.learning.features import feature_matrix, rotational_displacement
from proprio.learning.models import ARCHS, HybridModel, ModelConfig, load_model
from proprio.learning.training import TrainConfig, train_model
from proprio.plant import build_plant
from proprio.systems.observers import JacobianWrenchObserver, WrenchMap
from proprio.systems.residual_network import AddResidualNetwork

N = 7
RATE = 75.0


def _synthetic(samples: int, seed: int = 0) -> PreparedRecording:
    rng = np.random.default_rng(seed)
    t = np.arange(samples) / RATE
    w = rng.uniform(0.1, 0.6, N)
    q = 0.5 * np.sin(np.outer(t, w)) + 0.02 * np.sin(np.outer(t, 3 * w))
    qd, qdd = np.gradient(q, t, axis=0), np.gradient(np.gradient(q, t, axis=0), t, axis=0)
    tau_rbd = 10 * np.sin(q)
    tau = tau_rbd + 0.3 * np.tanh(20 * qd) + rng.normal(0, 0.05, q.shape)
    return PreparedRecording("synthetic", t, feature_matrix(tau_rbd, q, qd, qdd, rotational_displacement(q)), tau)


def bench_training(samples: int, epochs: int) -> None:
    print(f"Training time per epoch, CPU, {torch.get_num_threads()} thread(s), {samples} samples at {RATE:.0f} Hz "
          f"(80 % train), batch 32 windows")
    prep = _synthetic(samples)
    print(f"{'model':<22} {'T':>4} {'s/epoch':>9} {'train samples/s':>16}")
    for arch in ARCHS:
        for window in ((100, 500) if arch == "transformer" else (100,)):
            data = DataConfig(window=window)
            split = make_split([prep], data)
            model = HybridModel(ModelConfig(arch=arch, window=window, rate_hz=RATE))
            result = train_model(model, split, TrainConfig(max_epochs=epochs, batch_size=32), progress=False)
            spe = result.seconds_per_epoch
            n_train = split.train.features.shape[0] * window
            print(f"{model.cfg.label():<22} {window:>4} {spe:>9.2f} {n_train / spe:>16.0f}")


def _replay_source(builder: DiagramBuilder, values: np.ndarray) -> Demultiplexer:
    """Zero-order hold of ``values [N, 4n]`` = [q, q̇, q̈, τ_J] centred on the sample times, split in 4 ports."""
    t = np.arange(len(values)) / RATE
    breaks = np.concatenate([t - 0.5 / RATE, [t[-1] + 0.5 / RATE]])
    src = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(breaks, np.vstack([values, values[-1:]]).T)))
    demux = builder.AddSystem(Demultiplexer([N] * 4))
    builder.Connect(src.get_output_port(), demux.get_input_port())
    return demux


REPEATS = 3


def _timed(diagram: Diagram, steps: int) -> float:
    """Median over REPEATS fresh simulations of ``diagram``: µs per sample (one step per sample at RATE)."""
    runs = []
    for _ in range(REPEATS):
        sim = Simulator(diagram)
        sim.Initialize()
        t0 = time.perf_counter()
        sim.AdvanceTo((steps - 1) / RATE)
        runs.append((time.perf_counter() - t0) / steps * 1e6)
    return float(np.median(runs))


def bench_streaming(steps: int) -> None:
    torch.set_num_threads(1)
    desc = load_robot("iiwa14_identified")
    rng = np.random.default_rng(0)
    t = np.arange(steps) / RATE
    q = 0.3 * np.sin(np.outer(t, rng.uniform(0.2, 0.8, N))) + np.array([0, 0.5, 0, -1.2, 0, 0.8, 0])
    qd, qdd = np.gradient(q, t, axis=0), np.gradient(np.gradient(q, t, axis=0), t, axis=0)
    values = np.hstack([q, qd, qdd, rng.normal(0, 1, q.shape)])
    model = HybridModel(ModelConfig(arch="lstm2_fcl", rate_hz=RATE))
    model.set_normalisation(feature_matrix(values[:, 21:], q, qd, qdd, rotational_displacement(q)), values[:, 21:])

    def estimator(with_observer: bool) -> float:
        """replay → InverseDynamics → residual LSTM [→ Jacobian observer] → logger; µs per sample."""
        builder = DiagramBuilder()
        demux = _replay_source(builder, values)
        state = builder.AddSystem(Multiplexer([N, N]))
        rbd = builder.AddSystem(InverseDynamics(plant, InverseDynamics.InverseDynamicsMode.kInverseDynamics))
        builder.Connect(demux.get_output_port(0), state.get_input_port(0))
        builder.Connect(demux.get_output_port(1), state.get_input_port(1))
        builder.Connect(state.get_output_port(), rbd.get_input_port_estimated_state())
        builder.Connect(demux.get_output_port(2), rbd.get_input_port_desired_acceleration())
        residual = AddResidualNetwork(builder, model)
        for i, name in enumerate(("q", "qd", "qdd")):
            builder.Connect(demux.get_output_port(i), residual.GetInputPort(name))
        builder.Connect(rbd.get_output_port_generalized_force(), residual.GetInputPort("tau_rbd"))
        if not with_observer:
            LogVectorOutput(residual.GetOutputPort("tau_hybrid"), builder, 1 / RATE)
            return _timed(builder.Build(), steps)
        observer = builder.AddSystem(JacobianWrenchObserver(N))
        wrench = builder.AddSystem(WrenchMap(desc, sources=("jacobian",)))
        builder.Connect(demux.get_output_port(3), observer.GetInputPort("tau_meas"))
        builder.Connect(residual.GetOutputPort("tau_hybrid"), observer.GetInputPort("tau_dyn"))
        builder.Connect(demux.get_output_port(0), wrench.GetInputPort("q"))
        builder.Connect(observer.GetOutputPort("tau_ext"), wrench.GetInputPort("tau_ext_jacobian"))
        LogVectorOutput(wrench.GetOutputPort("wrench_jacobian"), builder, 1 / RATE)
        return _timed(builder.Build(), steps)

    plant = build_plant(desc).plant          # kinematics/dynamics only: not simulated in these Diagrams
    full, no_observer = estimator(True), estimator(False)

    # (b) replay + residual System alone (τ_RBD input from the replay)
    builder = DiagramBuilder()
    demux = _replay_source(builder, values)
    residual = AddResidualNetwork(builder, model)
    for i, name in enumerate(("q", "qd", "qdd", "tau_rbd")):
        builder.Connect(demux.get_output_port(i), residual.GetInputPort(name))
    LogVectorOutput(residual.GetOutputPort("tau_hybrid"), builder, 1 / RATE)
    alone = _timed(builder.Build(), steps)

    # (c) the estimation diagram of `proprio estimate --model hybrid.pt`: the rigid-body stage (τ_rigid, momentum terms
    # and J on one plant context, M(q) three times), the torque step (friction + residual), both observers, one logger
    hybrid = HybridTorqueModel(RigidBodyTorqueModel(desc), model, DataConfig())
    signals = {"t": t, "q": q, "qd": qd, "qdd": qdd, "tau": values[:, 21:], "time_step": 1 / RATE}
    estimation = _timed(build_estimation_diagram(hybrid, signals)[0], steps)   # (stages not started: timing only)

    # (d) replay + logger only: the Diagram overhead the rows above include
    builder = DiagramBuilder()
    demux = _replay_source(builder, values)
    LogVectorOutput(demux.get_output_port(3), builder, 1 / RATE)
    overhead = _timed(builder.Build(), steps)

    print(f"\nStreaming hybrid estimator, one sample per step at {RATE:.0f} Hz, {steps} steps, 1 torch thread, median "
          f"of {REPEATS} runs:")
    print(f"  replay + InverseDynamics (C++) + residual LSTM-2-FCL + Jacobian observer + logger: {full:7.1f} µs/sample"
          f"  (target ≤ 100; real-time factor at {RATE:.0f} Hz: {1e6 / RATE / full:.0f}×)")
    print(f"  replay + InverseDynamics (C++) + residual LSTM-2-FCL + logger (no observer):      {no_observer:7.1f} µs/sample")
    print(f"  replay + residual LSTM-2-FCL System + logger:                                    {alone:7.1f} µs/sample")
    print(f"  replay + logger only (Diagram overhead included above):                          {overhead:7.1f} µs/sample")
    print(f"  estimation diagram with a hybrid .pt (backbone + residual + BOTH observers):      {estimation:7.1f} "
          "µs/sample")


def report_trained(paths: list[Path]) -> None:
    """Per saved model: epochs, s/epoch, its best epoch (1-based, as ``proprio train`` prints it), the time to reach
    it [min] and its test MSE [N·m²] (windowed and streaming, averaged over joints), from the history ``proprio
    train`` stores in the file."""
    print(f"{'model file':<28} {'epochs':>6} {'s/epoch':>8} {'best':>5} {'to best [min]':>14} {'test MSE':>9} "
          f"{'streaming':>9}")
    for path in paths:
        model, extra = load_model(path)
        hist = extra.get("history") or []
        if not hist:
            print(f"{str(path):<28} no training history in the file")
            continue
        best = int(extra.get("best_epoch", -1))
        to_best = sum(h["seconds"] for h in hist if h["epoch"] <= best) / 60.0 if best >= 0 else float("nan")
        mse = {name: float(np.mean(v["test"])) for name, v in extra.get("mse", {}).items()}
        label = model.cfg.label()
        print(f"{str(path):<28} {len(hist):>6} {np.mean([h['seconds'] for h in hist]):>8.2f} {best + 1:>5} "
              f"{to_best:>14.1f} {mse.get(label, float('nan')):>9.4f} "
              f"{mse.get(label + ' (streaming)', float('nan')):>9.4f}")


def bench_batch_inference(minutes: float) -> None:
    """CPU s and samples/s of torch's streaming forward and of the numba batch law over one ``minutes``-long log."""
    print(f"\nBatch streaming inference over one {minutes:g}-minute log (float64, 1 thread, CPU time, best of 3)")
    print(f"{'model':<16}{'rate':>8}{'samples':>9}{'torch run':>14}{'numba/numpy':>14}{'speed-up':>10}{'max |Δ| N·m':>13}")
    for rate in (RATE, 1000.0):
        samples = int(minutes * 60 * rate)
        rng = np.random.default_rng(0)
        t = np.arange(samples) / rate
        w = rng.uniform(0.1, 0.6, N)
        q = 0.5 * np.sin(np.outer(t, w)) + 0.02 * np.sin(np.outer(t, 3 * w))
        qd, qdd = 0.5 * w * np.cos(np.outer(t, w)), -0.5 * w ** 2 * np.sin(np.outer(t, w))
        x = feature_matrix(10 * np.sin(q), q, qd, qdd, rotational_displacement(q))
        for arch in ("mlp7", "lstm2", "lstm2_fcl"):
            torch.manual_seed(0)
            model = HybridModel(ModelConfig(arch=arch, rate_hz=rate))
            with torch.no_grad():                       # a network that does something (untrained: τ_RBD exactly)
                for p in model.net.parameters():
                    p.copy_(0.3 * torch.randn_like(p))
            model.set_normalisation(x, x[:, :N] + rng.normal(0, 0.3, (samples, N)))
            model = model.double().eval()

            def torch_run() -> np.ndarray:
                with torch.no_grad():
                    return model.run(torch.as_tensor(x[None]))[0][0].numpy()

            times, out = {}, {}
            for name, run in (("torch", torch_run), ("numba", lambda: predict_streaming(model, x))):
                best = np.inf
                for _ in range(3):
                    start = time.process_time()
                    out[name] = run()
                    best = min(best, time.process_time() - start)
                times[name] = best
            diff = float(np.abs(out["torch"] - out["numba"]).max())
            print(f"{model.cfg.label():<16}{rate:>6.0f}Hz{samples:>9}{samples / times['torch'] / 1e3:>10.1f} k/s"
                  f"{samples / times['numba'] / 1e3:>10.1f} k/s{times['torch'] / times['numba']:>9.2f}×{diff:>13.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20000, help="training samples per epoch benchmark")
    parser.add_argument("--epochs", type=int, default=2, help="epochs timed per architecture")
    parser.add_argument("--steps", type=int, default=3000, help="Diagram steps timed")
    parser.add_argument("--log-minutes", type=float, default=10.0, help="length of the batch-inference log [min]")
    parser.add_argument("--batch-only", action="store_true", help="time only the batch inference, then stop")
    parser.add_argument("--trained", nargs="+", type=Path, default=[], metavar="MODEL",
                        help="saved models (.pt): report their training time to the best epoch, then stop")
    args = parser.parse_args()
    if args.trained:
        report_trained(args.trained)
        return
    torch.set_num_threads(1)
    if args.batch_only:
        bench_batch_inference(args.log_minutes)
        return
    bench_streaming(args.steps)
    bench_batch_inference(args.log_minutes)
    bench_training(args.samples, args.epochs)


if __name__ == "__main__":
    main()
