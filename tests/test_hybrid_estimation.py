"""The hybrid model in the estimation diagram: the network runs online as its own stage (ResidualNetworkSystem after
the backbone's TorqueModelSystem, Adders summing τ_RBD + τ_NN) and matches the offline streaming path; its backbone
and preprocessing are the training ones."""
import numpy as np
import pytest
import torch

from proprio.description import load_robot
from pydrake.systems.primitives import Adder

from proprio.diagrams.estimation import (TorqueModelSystem, WrenchEstimator, estimate_wrench, estimate_wrench_offline,
                                         load_torque_model)
from proprio.diagrams.hybrid_torque_model import HybridTorqueModel
from proprio.dynamics import inverse_dynamics
from proprio.learning.datasets import DataConfig, prepare_recording
from proprio.learning.features import rbd_provider
from proprio.learning.models import HybridModel, ModelConfig, save_model
from proprio.payload import Payload, attach_payload
from proprio.recording import Recording, RecordingError
from proprio.systems.residual_network import ResidualNetworkSystem

RATE = 150.0
DATA = DataConfig(decimate=2, window=20, cutoff_hz=10.0, tau_filter_hz=5.0)


@pytest.fixture(scope="module")
def desc():
    return load_robot("iiwa14_identified")


def _recording(desc, seconds=8.0, rate=RATE, mass=1.0, seed=0) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    w = rng.uniform(0.3, 0.9, desc.n)
    home = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
    q = home + 0.3 * np.sin(np.outer(t, w))
    qd = 0.3 * w * np.cos(np.outer(t, w))
    qdd = -0.3 * w ** 2 * np.sin(np.outer(t, w))
    tau = inverse_dynamics(attach_payload(desc, Payload(mass)), q, qd, qdd) + rbd_provider(desc)(q, qd, qdd) \
        - inverse_dynamics(desc, q, qd, qdd) + rng.normal(0, 0.05, q.shape)
    return Recording(t=t, q=q, tau=tau, meta={"robot": desc.name})


def _model_file(tmp_path, desc, arch="lstm2_fcl", hybrid=True):
    torch.manual_seed(0)
    cfg = ModelConfig(arch=arch, hybrid=hybrid, window=20, lstm_hidden=6, mlp_hidden=8, tf_d_model=8, tf_heads=2,
                      tf_layers=1, tf_ff=16, rate_hz=RATE / DATA.decimate)
    model = HybridModel(cfg)
    with torch.no_grad():                     # as if trained: an untrained hybrid predicts τ_RBD exactly
        for p in model.net.parameters():
            p.copy_(0.3 * torch.randn_like(p))
    prep = prepare_recording(_recording(desc, seed=5), rbd_provider(desc), DATA)
    model.set_normalisation(prep.features, prep.tau)
    return save_model(model, tmp_path / f"{arch}.pt", {"backbone": desc.name, "data": DATA.to_dict()})


def test_backbone_and_signals_are_the_training_ones(tmp_path, desc):
    hybrid = load_torque_model(_model_file(tmp_path, desc))
    assert isinstance(hybrid, HybridTorqueModel) and hybrid.description.name == desc.name
    rec = _recording(desc)
    at_rate, sig = hybrid.signals(rec)
    prep = prepare_recording(rec, rbd_provider(desc), DATA)
    np.testing.assert_allclose(hybrid.tau_backbone(sig["q"], sig["qd"], sig["qdd"]), prep.tau_rbd, atol=1e-10)
    np.testing.assert_array_equal(at_rate.t, prep.t)
    np.testing.assert_array_equal(sig["tau"], prep.tau)
    assert sig["time_step"] == pytest.approx(2 / RATE)


def test_network_runs_online_in_the_diagram_and_equals_offline(tmp_path, desc):
    hybrid = load_torque_model(_model_file(tmp_path, desc))
    rec = _recording(desc, seconds=6.0)
    online, offline = estimate_wrench(hybrid, rec), estimate_wrench_offline(hybrid, rec)
    assert online.t.shape == (rec.n_samples // 2,) and online.meta["model"] == "lstm2_fcl.pt"
    # the network's residual is not zero, so the equality below exercises its online state
    assert np.abs(hybrid.tau_int(*(hybrid.signals(rec)[1][k] for k in ("q", "qd", "qdd")))).max() > 0.1
    # sample for sample (the momentum estimate at k is r_{k−1} in both; its recursion sums rounding: 1e-8)
    for obs, atol in (("jacobian", 1e-9), ("momentum", 1e-8)):
        np.testing.assert_allclose(online.wrench[obs], offline.wrench[obs], rtol=0, atol=atol)
        np.testing.assert_allclose(online.tau_ext[obs], offline.tau_ext[obs], rtol=0, atol=atol)


def test_the_network_is_its_own_stage_of_the_diagram(tmp_path, desc):
    """Design card: features → RBD backbone τ_RBD → residual network τ_NN → observers, one System per stage; the
    sums τ_RBD + τ_NN and τ_int,RBD + τ_NN are C++ Adders."""
    hybrid = load_torque_model(_model_file(tmp_path, desc))
    est = WrenchEstimator(hybrid, 1 / hybrid.rate_hz)
    stages = {s.get_name(): s for s in est.GetSystems()}
    assert {"rigid_body", "torque_model", "residual_network", "tau_dyn", "tau_int", "jacobian_observer",
            "momentum_observer", "wrench"} <= set(stages)
    assert isinstance(stages["residual_network"], ResidualNetworkSystem)
    assert isinstance(stages["tau_dyn"], Adder) and isinstance(stages["tau_int"], Adder)
    residual = stages["residual_network"]
    assert [residual.get_input_port(i).get_name() for i in range(residual.num_input_ports())] == \
        ["tau_rbd", "q", "qd", "qdd"]
    assert residual.GetOutputPort("tau_nn").size() == desc.n
    with pytest.raises(ValueError, match="memory"):            # the backbone stage takes no network
        TorqueModelSystem(hybrid)


@pytest.mark.parametrize("arch", ["mlp7", "lstm2"])
def test_a_standalone_network_runs_in_the_diagram_and_equals_offline(tmp_path, desc, arch):
    """A standalone network (no τ_RBD in or added): τ_dyn = τ_NN, τ_int = τ_NN − τ_rigid in the Diagram too."""
    model = load_torque_model(_model_file(tmp_path, desc, arch=arch, hybrid=False))
    rec = _recording(desc, seconds=4.0)
    online, offline = estimate_wrench(model, rec), estimate_wrench_offline(model, rec)
    for obs, atol in (("jacobian", 1e-9), ("momentum", 1e-8)):
        np.testing.assert_allclose(online.tau_ext[obs], offline.tau_ext[obs], rtol=0, atol=atol)


def test_a_recording_at_another_rate_is_decimated_or_rejected(tmp_path, desc):
    hybrid = load_torque_model(_model_file(tmp_path, desc))
    at_rate, sig = hybrid.signals(_recording(desc, seconds=3.0, rate=750.0))       # every 10th sample → 75 Hz
    assert sig["time_step"] == pytest.approx(1 / 75.0) and at_rate.n_samples == 225
    with pytest.raises(RecordingError, match="model rate"):
        hybrid.signals(_recording(desc, seconds=3.0, rate=110.0))
    # a jittered log is conditioned onto the uniform grid of its median step first, then decimated
    rec = _recording(desc, seconds=3.0)
    jittered = rec.replace(t=rec.t + np.random.default_rng(0).uniform(0, 2e-3, rec.n_samples))
    at_rate, sig = hybrid.signals(jittered)
    steps = np.diff(at_rate.t)
    np.testing.assert_allclose(steps, steps[0], rtol=1e-9)
    assert sig["time_step"] == pytest.approx(steps[0]) and abs(1 / steps[0] - 75.0) < 0.02 * 75.0
    # a log alternating 6 and 7 ms steps (the twin's "150 Hz"): grid at the median step, every 2nd sample
    alternating = rec.replace(t=np.concatenate([[0.0], np.cumsum(np.tile([0.006, 0.007], rec.n_samples // 2))])[
        :rec.n_samples])
    hybrid.network.cfg.rate_hz = 1 / 0.013
    at_rate, sig = hybrid.signals(alternating)
    np.testing.assert_allclose(np.diff(at_rate.t), np.diff(at_rate.t)[0], rtol=1e-9)
    assert abs(sig["time_step"] - 0.013) < 0.02 * 0.013


def test_a_twin_logs_at_a_rate_the_hybrid_reads(tmp_path, desc):
    """The payload experiment's twin logs at ``log_rate``: unchanged where a whole decimation reaches the model rate,
    else the rate of the hybrid's training recordings (1 kHz for a 75 Hz model trained at 150 Hz: 150 Hz)."""
    hybrid = load_torque_model(_model_file(tmp_path, desc))
    assert hybrid.rate_hz == pytest.approx(75.0) and DATA.decimate == 2
    assert hybrid.log_rate(750.0) == 750.0 and hybrid.log_rate(150.0) == 150.0
    assert hybrid.log_rate(1000.0) == pytest.approx(150.0)
    with pytest.raises(RecordingError, match="model rate"):
        hybrid.signals(_recording(desc, seconds=2.0, rate=1000.0))
    hybrid.signals(_recording(desc, seconds=2.0, rate=hybrid.log_rate(1000.0)))


def test_a_transformer_cannot_run_online(tmp_path, desc):
    with pytest.raises(ValueError, match="streaming"):
        load_torque_model(_model_file(tmp_path, desc, arch="transformer"))
