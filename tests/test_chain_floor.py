"""The floor of Table 5.4 through the hybrid's signal chain (``benchmarks/chain_floor.py``, README "Hybrid models on
the twin"): the twin's exact model, told only the conditioned measured channels, is what its laws allow; the lost
motion is the effect the chain follows worst, which is why the twin's is bounded by the thesis' Table 5.4."""
import numpy as np
import pytest
import torch

from proprio.description import load_robot
from proprio.diagrams.hybrid_torque_model import HybridTorqueModel
from proprio.diagrams.torque_model import RigidBodyTorqueModel
from proprio.diagrams.twin import load_twin_config
from proprio.experiments.hybrid import load_config
from proprio.learning.features import feature_matrix, rotational_displacement
from proprio.learning.models import HybridModel, ModelConfig
from proprio.recording import load_recording
from proprio.signals import MotionSignals

def _twin_recipe_chain() -> HybridTorqueModel:
    """A hybrid with ``train_hybrid_twin``'s signal chain (q and τ in the 5 Hz band, 75 Hz model rate) and a zero
    residual: its network plays no part in the exact model's figures, only its chain does."""
    data = load_config("train_hybrid_twin").data
    desc = load_robot("iiwa14_identified")
    torch.manual_seed(0)
    net = HybridModel(ModelConfig(arch="lstm2_fcl", lstm_hidden=8, rate_hz=75.0))
    q = np.zeros((10, desc.n)) + np.linspace(0, 1, 10)[:, None]
    net.set_normalisation(feature_matrix(q, q, q, q, rotational_displacement(q)), np.ones_like(q))
    net.zero_output()
    return HybridTorqueModel(RigidBodyTorqueModel(desc), net, data, "zero residual")


@pytest.fixture(scope="module")
def floor_runs(tmp_path_factory, benchmark_module):
    """Table 5.4's 0 g run (30 s, seed 7) on the calibrated twin and on the same twin with the earlier lost motion
    (10×: the Coulomb level the thesis' wording gave, before the Table 5.4 rule bounded it)."""
    cf = benchmark_module("chain_floor")
    hyb = _twin_recipe_chain()
    twin = load_twin_config("iiwa14_twin")
    earlier = [type(e)(e.n, amplitude=10 * e.amplitude, load_gain=10 * e.load_gain, window=e.window,
                       reversal_velocity=e.reversal_velocity) if e.name == "lost_motion" else e for e in twin.effects]
    runs = {}
    for label, effects in (("calibrated", twin.effects), ("earlier lost motion", earlier)):
        out = tmp_path_factory.mktemp(label.replace(" ", "_"))
        errors = cf.table54(hyb, out, 30.0, 7, twin.with_effects(effects), masses=(0.0,))
        runs[label] = (errors, out)
    return cf, runs


def test_the_exact_model_is_the_twins_own(floor_runs):
    """On the twin's true motion (its ``truth__*`` channels) the exact model predicts the logged τ to the sensor's
    white noise: it holds every deterministic law the twin simulated, with the twin's parameters."""
    cf, runs = floor_runs
    rec = load_recording(runs["calibrated"][1] / "twin_0g.npz")
    tr = rec.truth
    s = MotionSignals(tr["t_true"], tr["q_true"], tr["qd"], tr["qdd"])
    pred = cf.exact_torque(cf.exact_model(rec), s)
    resid = rec.tau - tr["tau_torque_noise"] - pred
    # the twin advances its sensor state at 1 kHz, the law here at the logged samples: a reversal is placed up to a
    # logging step apart, which moves the lost-motion window by that much travel (a few samples of the run)
    assert np.median(np.abs(resid)) < 1e-6
    assert np.mean(np.abs(resid) > 1e-3) < 0.01
    assert "lost_motion" in {e.name for e in cf.exact_model(rec).effects}


def test_the_calibrated_twins_exact_model_meets_the_theses_table_54_and_the_earlier_lost_motion_did_not(floor_runs):
    """Through train_hybrid_twin's chain the calibrated twin's exact model meets the thesis' 0 g error [0.08 0.09
    0.12] N on every axis (the calibration rule asks half of it on the 563 s run, benchmarks/chain_floor.py; this
    30 s run is a small sample), while the lost motion at the earlier amplitude keeps it above 0.15 N: its release
    and its slow-turn reversals are what the 5 Hz chain cannot follow."""
    _, runs = floor_runs
    rmse = {k: np.sqrt(np.mean(errors["exact model"][0.0] ** 2, axis=0)) for k, (errors, _) in runs.items()}
    assert np.all(rmse["calibrated"] <= np.array([0.08, 0.09, 0.12])), rmse
    assert np.max(rmse["earlier lost motion"]) > 0.15, rmse
