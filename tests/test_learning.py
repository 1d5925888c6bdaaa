"""Hybrid-model learning stack: r encoding, dataset protocol, models, training resume, the streaming System."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from proprio.learning.datasets import DataConfig, make_split, prepare_recording
from proprio.learning.evaluation import predict_streaming, predict_windowed
from proprio.learning.features import (ReversalEncoder, feature_columns, feature_matrix,
                                       rotational_displacement)
from proprio.learning.models import ARCHS, HybridModel, ModelConfig, StreamingStepper, load_model, save_model
from proprio.learning.training import TrainConfig, train_model
from proprio.recording import Recording
from proprio.systems.residual_network import AddResidualNetwork

torch.set_num_threads(1)
LWR = Path(__file__).resolve().parents[2] / "shared" / "data" / "kuka_lwr4"
N_J = 7


def _ramp(*knots_deg: float, step_deg: float = 0.02) -> np.ndarray:
    """Piecewise-linear joint path through the knots [deg], sampled every step_deg, returned in rad [N, 1]."""
    parts = [np.arange(a, b, step_deg if b > a else -step_deg) for a, b in zip(knots_deg[:-1], knots_deg[1:])]
    return np.radians(np.concatenate(parts + [[knots_deg[-1]]]))[:, None]


# -- rotational displacement encoding -----------------------------------------------------------------------------
def test_r_exact_values_at_known_reversals():
    q = _ramp(0.0, 5.0, -20.0, -18.0)                  # up 5°, down 25°, up 2°
    h = 0.05
    r = np.degrees(rotational_displacement(q, deadband_deg=h)[:, 0])
    qd = np.degrees(q[:, 0])
    i_peak, i_trough = int(np.argmax(qd)), int(np.argmin(qd))
    peak, trough = qd[i_peak], qd[i_trough]
    # up phase: travel from the start
    np.testing.assert_array_equal(r[:i_peak + 1], qd[:i_peak + 1])
    # reversal at the peak is confirmed once the joint is h below it; until then r still counts from the start
    i_conf = i_peak + int(np.argmax(peak - qd[i_peak:] > h + 1e-9))
    assert qd[i_conf] == pytest.approx(peak - 0.06)   # first sample more than 0.05° below the peak
    np.testing.assert_array_equal(r[i_peak:i_conf], qd[i_peak:i_conf])
    # from the confirmation on: travel since the peak, clipped at -10°
    np.testing.assert_allclose(r[i_conf:i_trough + 1], np.clip(qd[i_conf:i_trough + 1] - peak, -10, 10), atol=1e-12)
    assert r[i_trough] == -10.0
    # second reversal at the trough: travel since -20° once confirmed
    j_conf = i_trough + int(np.argmax(qd[i_trough:] - trough > h + 1e-9))
    np.testing.assert_allclose(r[j_conf:], qd[j_conf:] - trough, atol=1e-12)
    assert r[-1] == pytest.approx(2.0)


def test_r_clipped_to_ten_degrees():
    q = np.concatenate([_ramp(0.0, 40.0, -40.0, 0.0), _ramp(10.0, 170.0)], axis=1)
    r = np.degrees(rotational_displacement(q))
    assert r.max() == 10.0 and r.min() == -10.0
    assert np.all(np.abs(r) <= 10.0)


def test_r_robust_to_encoder_noise():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 40, 6000)
    clean = np.radians(np.stack([4 * np.sin(0.5 * t), 0.001 * t, 8 * np.sin(0.2 * t + 1)], axis=1))
    noisy = clean + rng.normal(0, np.radians(0.005), clean.shape)      # encoder noise σ = 0.005°
    r_clean = rotational_displacement(clean)
    err = np.degrees(np.abs(rotational_displacement(noisy) - r_clean))
    # a noisy sign flip is not a reversal: r follows the clean encoding except right at true reversals
    assert np.mean(err > 0.1) < 0.01
    # without a deadband every noisy sign flip restarts r — the encoding is destroyed
    err_naive = np.degrees(np.abs(rotational_displacement(noisy, deadband_deg=0.0) - r_clean))
    assert np.mean(err_naive > 0.1) > 0.5


def test_streaming_encoder_equals_offline_bit_for_bit():
    rng = np.random.default_rng(0)
    q = np.cumsum(rng.normal(0, 0.002, (3000, N_J)), axis=0) + np.radians(rng.normal(0, 0.02, (3000, N_J)))
    enc = ReversalEncoder(N_J)
    streamed = np.array([enc.step(x) for x in q])
    np.testing.assert_array_equal(streamed, rotational_displacement(q))


# -- dataset protocol -----------------------------------------------------------------------------------------------
def _recording(n_samples: int = 3000, seed: int = 0, rate: float = 150.0) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) / rate
    w = rng.uniform(0.2, 1.0, N_J)
    q = 0.4 * np.sin(np.outer(t, w) + rng.uniform(0, 6, N_J))
    qd, qdd = 0.4 * w * np.cos(np.outer(t, w)), -0.4 * w ** 2 * np.sin(np.outer(t, w))
    tau = 3 * np.sin(q) + 0.5 * qd + 0.1 * np.sign(qd) + rng.normal(0, 0.01, q.shape)
    return Recording(t=t, q=q, tau=tau, qd=qd, qdd=qdd, meta={"rate_hz": rate})


def _toy_backbone(q, qd, qdd):
    return 3 * np.sin(q)


def _split(window: int = 20, n_samples: int = 3000):
    cfg = DataConfig(window=window, decimate=2)
    prep = [prepare_recording(_recording(n_samples, s), _toy_backbone, cfg, f"r{s}") for s in (0, 1)]
    return make_split(prep, cfg), prep, cfg


def test_split_uses_whole_subsequences_and_keeps_their_order():
    split, prep, cfg = _split()
    assert split.rate_hz == pytest.approx(75.0)
    assert prep[0].features.shape == (1500, 5 * N_J)
    total = sum(p.tau.shape[0] // cfg.window for p in prep)
    assert len(split.train) + len(split.val) + len(split.test) == total
    assert len(split.test) == round(0.2 * total)
    seen = set()
    for w in (split.train, split.val, split.test):
        for k, (rec, start) in enumerate(w.origin):
            assert start % cfg.window == 0 and (rec, start) not in seen
            seen.add((rec, start))
            np.testing.assert_array_equal(w.features[k], prep[rec].features[start:start + cfg.window])
    again, _, _ = _split()
    np.testing.assert_array_equal(again.test.origin, split.test.origin)   # seeded


def test_normalisation_comes_from_the_training_split_only():
    split, _, _ = _split()
    model = HybridModel(ModelConfig(arch="mlp7", mlp_hidden=8))
    model.set_normalisation(split.train.features, split.train.tau)
    cols = feature_columns(N_J, True, True)
    x = split.train.features.reshape(-1, 5 * N_J)[:, cols]
    np.testing.assert_allclose(model.x_mean.numpy(), x.mean(0), rtol=1e-5, atol=1e-6)
    resid = split.train.tau.reshape(-1, N_J) - split.train.features.reshape(-1, 5 * N_J)[:, :N_J]
    np.testing.assert_allclose(model.y_std.numpy(), resid.std(0), rtol=1e-5)


# -- models ---------------------------------------------------------------------------------------------------------
def _as_trained(model: HybridModel) -> HybridModel:
    """Random weights everywhere: an untrained hybrid's output is exactly τ_RBD (its last layer starts at zero),
    which would make the checks below on the network's output trivial."""
    with torch.no_grad():
        for p in model.net.parameters():
            p.copy_(0.3 * torch.randn_like(p))
    return model


def _small(arch: str, hybrid: bool = True, use_r: bool = True, window: int = 20) -> ModelConfig:
    return ModelConfig(arch=arch, hybrid=hybrid, use_r=use_r, window=window, mlp_hidden=8, lstm_hidden=6,
                       tf_d_model=8, tf_heads=2, tf_layers=1, tf_ff=16)


@pytest.mark.parametrize("arch", ARCHS)
def test_saved_and_loaded_model_predicts_identically(arch, tmp_path):
    split, _, _ = _split()
    torch.manual_seed(0)
    model = _as_trained(HybridModel(_small(arch, hybrid=arch != "mlp7", use_r=arch != "lstm2")))
    model.set_normalisation(split.train.features, split.train.tau)
    path = save_model(model, tmp_path / "m.pt", {"note": "test"})
    loaded, extra = load_model(path)
    assert extra == {"note": "test"} and loaded.cfg == model.cfg
    np.testing.assert_array_equal(predict_windowed(loaded, split.test.features),
                                  predict_windowed(model.eval(), split.test.features))


def test_hybrid_adds_tau_rbd_and_standalone_ignores_it():
    torch.manual_seed(0)
    x = torch.randn(2, 5, 5 * N_J)
    x2 = x.clone()
    x2[..., :N_J] += 1.0
    hyb, alone = HybridModel(_small("lstm2_fcl")), HybridModel(_small("lstm2_fcl", hybrid=False))
    assert hyb.cfg.n_inputs == 35 and alone.cfg.n_inputs == 28 and HybridModel(_small("mlp7", use_r=False)).cfg.n_inputs == 28
    torch.testing.assert_close(alone(x2), alone(x))
    torch.testing.assert_close(hyb(x), x[..., :N_J], rtol=0, atol=0)   # an untrained residual is exactly zero
    torch.nn.init.normal_(hyb.net.fcl.weight)                           # as after training
    assert not torch.allclose(hyb(x2) - hyb(x), torch.ones(1))   # τ_RBD also enters the network


def test_mlp7_nets_are_independent_per_joint():
    model = HybridModel(_small("mlp7"))
    torch.nn.init.normal_(model.net.w2)                  # the zero start would hide w1's gradients
    x = torch.randn(4, 3, 35)
    out = model(x)
    out[..., 2].sum().backward()
    grads = model.net.w1.grad.abs().sum(dim=(1, 2))
    assert grads[2] > 0 and torch.all(grads[[0, 1, 3, 4, 5, 6]] == 0)


@pytest.mark.parametrize("arch", ["lstm2", "lstm2_fcl", "transformer"])
def test_sequence_models_are_causal(arch):
    torch.manual_seed(1)
    model = _as_trained(HybridModel(_small(arch))).eval()
    x = torch.randn(1, 20, 35)
    x2 = x.clone()
    x2[:, 12:] += 1.0
    with torch.no_grad():
        torch.testing.assert_close(model(x2)[:, :12], model(x)[:, :12])


# -- training ---------------------------------------------------------------------------------------------------------
class _Killed(RuntimeError):
    pass


def test_training_learns_the_residual():
    split, _, _ = _split()
    torch.manual_seed(0)
    model = HybridModel(_small("mlp7"))
    result = train_model(model, split, TrainConfig(max_epochs=30, batch_size=8, early_stop_patience=30), progress=False)
    assert result.history[-1]["train"] < 0.3 * result.history[0]["train"]


@pytest.mark.parametrize("kind, power", [("nm2", 0), ("inv_std", 1), ("normalised", 2)])
def test_loss_weights_each_joint_by_a_power_of_its_target_std(kind, power):
    from proprio.learning.training import _loss
    split, _, _ = _split()
    torch.manual_seed(0)
    model = HybridModel(_small("mlp7"))
    model.set_normalisation(split.train.features, split.train.tau)
    x, tau = (torch.as_tensor(a[:4], dtype=torch.float32) for a in (split.train.features, split.train.tau))
    expected = ((model(x) - tau) ** 2 / model.y_std ** power).mean()
    assert _loss(model, x, tau, kind).item() == pytest.approx(expected.item(), rel=1e-6)
    with pytest.raises(ValueError, match="inv_std"):
        TrainConfig.from_dict({"loss": "l1"})


def test_payload_table_runs_a_transformer_windowed(tmp_path):
    from proprio.description import load_robot
    from proprio.experiments.hybrid import Backbone, payload_table
    cfg = DataConfig(window=20, decimate=2)
    rec = _recording(1200, 3)
    rec = rec.replace(f_ext=np.zeros((rec.n_samples, 6)))
    models = {}
    for arch in ("lstm2_fcl", "transformer"):
        torch.manual_seed(0)
        models[arch] = _as_trained(HybridModel(_small(arch)))
        prep = prepare_recording(rec, _toy_backbone, cfg)
        models[arch].set_normalisation(prep.features, prep.tau)
    text = payload_table({"RBD": None, **models}, Backbone("toy", load_robot("iiwa14_identified"), _toy_backbone),
                         {"0 g": rec}, cfg)
    rows = text.splitlines()[1:]
    assert [r.split()[0] for r in rows] == ["RBD", "lstm2_fcl", "transformer"] and "(windowed)" in rows[2]
    assert all(np.isfinite(float(v)) for r in rows for v in r.split("[")[1].split("]")[0].split())


def test_the_same_config_trains_the_same_model(tmp_path):
    """Initial weights, batch order and training all follow ``train.seed``: whatever the global torch RNG did
    before (another model, another process), the same config gives bit-identical weights."""
    from proprio.experiments.hybrid import Backbone, train_from_config, training_config
    from proprio.description import load_robot
    cfg = training_config({"model": {"arch": "lstm2_fcl", "lstm_hidden": 6}, "data": {"window": 20},
                           "train": {"max_epochs": 2, "batch_size": 8, "seed": 3}}, "test")
    backbone = Backbone("toy", load_robot("iiwa14_identified"), _toy_backbone)
    recs = [_recording(3000, s) for s in (0, 1)]
    weights = []
    for k in range(2):
        torch.manual_seed(100 + k)                       # a different global RNG state each time
        model, _, _ = train_from_config(cfg, recs, backbone, tmp_path / f"m{k}.pt", progress=False)
        weights.append(model.state_dict())
    for name, value in weights[0].items():
        assert torch.equal(value, weights[1][name]), name


def test_resume_after_a_killed_run_continues_from_the_last_epoch(tmp_path):
    split, _, _ = _split()
    cfg = TrainConfig(max_epochs=5, batch_size=8, early_stop_patience=100)
    torch.manual_seed(0)
    reference = HybridModel(_small("lstm2_fcl"))
    init = {k: v.clone() for k, v in reference.state_dict().items()}
    ref = train_model(reference, split, cfg, checkpoint=tmp_path / "ref.ckpt", progress=False)

    def kill_after_epoch_2(epoch, record):
        if epoch == 2:
            raise _Killed

    model = HybridModel(_small("lstm2_fcl"))
    model.load_state_dict(init)
    with pytest.raises(_Killed):
        train_model(model, split, cfg, checkpoint=tmp_path / "run.ckpt", progress=False, on_epoch_end=kill_after_epoch_2)
    epochs_after = []
    fresh = HybridModel(_small("lstm2_fcl"))          # a new process: different initial weights, restored from disk
    res = train_model(fresh, split, cfg, checkpoint=tmp_path / "run.ckpt", progress=False,
                      on_epoch_end=lambda e, r: epochs_after.append(e))
    assert epochs_after == [3, 4]
    assert [h["train"] for h in res.history] == [h["train"] for h in ref.history]
    for k, v in reference.state_dict().items():
        torch.testing.assert_close(fresh.state_dict()[k], v, rtol=0, atol=0)


# -- streaming: offline model == numpy stepper == Drake System ------------------------------------------------------
def _sequence(n: int = 200, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 75.0
    q = 0.3 * np.sin(np.outer(t, np.linspace(0.5, 2.0, N_J))) + rng.normal(0, 1e-4, (n, N_J))
    return feature_matrix(rng.normal(0, 5, (n, N_J)), q, rng.normal(size=(n, N_J)), rng.normal(size=(n, N_J)),
                          rotational_displacement(q))


def _torch_streaming(model: HybridModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """torch's streaming forward (the training form, autograd) over one sequence: (τ [N, n], final state)."""
    with torch.no_grad():
        tau, state = model.run(torch.as_tensor(x[None], dtype=torch.float64))
    return tau[0].numpy(), state[0].numpy()


@pytest.mark.parametrize("arch,hybrid,use_r", [("mlp7", True, True), ("mlp7", False, True), ("lstm2", True, True),
                                               ("lstm2", False, False), ("lstm2_fcl", True, True),
                                               ("lstm2_fcl", True, False)])
def test_batch_inference_kernel_equals_torch_forward(arch, hybrid, use_r):
    """The batch inference (predict_streaming: the streaming step's compiled kernel looped over the log in one call,
    MLP-7's law vectorised) equals torch's forward in float64, and :meth:`StreamingStepper.run` carries the state."""
    x = _sequence(300, seed=3)
    torch.manual_seed(4)
    model = _as_trained(HybridModel(_small(arch, hybrid=hybrid, use_r=use_r)))
    model.set_normalisation(x, x[:, :N_J] + np.random.default_rng(5).normal(0, 0.3, (len(x), N_J)))
    model = model.double().eval()
    reference, final = _torch_streaming(model, x)
    assert np.abs(reference - (x[:, :N_J] if hybrid else 0.0)).max() > 0.1         # a network that does something
    np.testing.assert_allclose(predict_streaming(model, x), reference, rtol=0, atol=1e-9)
    stepper = StreamingStepper(model)
    head, state = stepper.run(x[:120])                    # two calls with the state carried equal one call
    tail, state = stepper.run(x[120:], state)
    np.testing.assert_allclose(np.vstack([head, tail]), reference, rtol=0, atol=1e-9)
    np.testing.assert_allclose(state, final, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="features"):
        stepper.run(x[:, :-1])


@pytest.mark.parametrize("arch", ["mlp7", "lstm2", "lstm2_fcl"])
def test_streaming_system_equals_offline_model(arch):
    x = _sequence()
    torch.manual_seed(2)
    model = _as_trained(HybridModel(_small(arch, hybrid=arch != "lstm2")))
    model.set_normalisation(x, x[:, :N_J] + np.random.default_rng(1).normal(0, 0.3, (len(x), N_J)))
    model = model.double()
    offline = _torch_streaming(model, x)[0]
    # a stateless MLP and the windowed LSTM on its first window agree with streaming
    np.testing.assert_allclose(predict_windowed(model, x)[:model.cfg.window], offline[:model.cfg.window], atol=1e-12)
    stepper, state, stepped = StreamingStepper(model), np.zeros(model.state_size), []
    for row in x:
        tau, state = stepper.step(row, state)
        stepped.append(tau)
    np.testing.assert_allclose(np.array(stepped), offline, atol=1e-12)

    builder = DiagramBuilder()
    n, period = len(x), 1 / 75.0
    t = np.arange(n) * period
    q, qd, qdd, tau_rbd = x[:, 7:14], x[:, 14:21], x[:, 21:28], x[:, :7]
    values = np.hstack([q, qd, qdd, tau_rbd])
    # zero-order hold centred between samples so sample k is held around t_k
    src = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        np.concatenate([t - period / 2, [t[-1] + period / 2]]), np.vstack([values, values[-1:]]).T)))
    demux = builder.AddSystem(Demultiplexer([N_J] * 4))
    builder.Connect(src.get_output_port(), demux.get_input_port())
    system = AddResidualNetwork(builder, model)
    for i, name in enumerate(("q", "qd", "qdd", "tau_rbd")):
        builder.Connect(demux.get_output_port(i), system.GetInputPort(name))
    log = LogVectorOutput(system.GetOutputPort("tau_hybrid"), builder, period)
    log_res = LogVectorOutput(system.GetOutputPort("tau_nn"), builder, period)
    sim = Simulator(builder.Build())
    sim.AdvanceTo(t[-1] + 0.5 * period)
    logged = log.FindLog(sim.get_context()).data().T
    # direct feedthrough: the logger at t_k sees the prediction for the inputs of t_k, no sample of latency
    assert logged.shape == (n, N_J)
    np.testing.assert_allclose(logged, offline, atol=1e-12)
    # tau_nn: the network's own output (a hybrid's residual; a standalone model's torque)
    np.testing.assert_allclose(log_res.FindLog(sim.get_context()).data().T,
                               offline - (tau_rbd if model.cfg.hybrid else 0.0), atol=1e-12)


def test_transformer_is_rejected_by_the_system():
    with pytest.raises(ValueError, match="streaming"):
        AddResidualNetwork(DiagramBuilder(), HybridModel(_small("transformer")))


# -- real data + CLI ----------------------------------------------------------------------------------------------------
@pytest.mark.skipif(not LWR.exists(), reason="shared LWR 4+ data not present")
def test_cli_train_and_evaluate_on_lwr4(tmp_path, capsys):
    from proprio.cli import main
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("model: {arch: mlp7, mlp_hidden: 16}\ndata: {window: 50, trim_s: 0.5}\n"
                   "train: {max_epochs: 2, batch_size: 16}\n")
    data = [str(LWR / f"measurements_{i}.npz") for i in (2, 3)]
    args = ["--data", *data, "--test-data", str(LWR / "measurements_1.npz"), "--backbone", str(LWR)]
    assert main(["train", "--config", str(cfg), *args, "--out", str(tmp_path / "m.pt")]) == 0
    trained = capsys.readouterr().out
    assert "RBD" in trained and "MLP-7 no τ_RBD" not in trained and (tmp_path / "m.pt").exists()
    assert not (tmp_path / "m.pt.ckpt").exists()
    assert main(["evaluate", "--model", str(tmp_path / "m.pt"), *args]) == 0
    evaluated = capsys.readouterr().out
    rbd = lambda out: next(line for line in out.splitlines() if line.startswith("RBD"))  # noqa: E731
    assert rbd(evaluated) == rbd(trained)                            # the same RBD row
    assert sum("conditioning:" in line for line in trained.splitlines()) == 3     # one line per recording
    assert main(["train", "--config", "no_such_config", *args, "--out", str(tmp_path / "x.pt")]) == 2
