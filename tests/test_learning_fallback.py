"""A hybrid residual never makes its backbone worse on held-out data: it starts at exactly zero, and where it does
not beat τ_RBD on the validation split it falls back to it (whole model or per joint), which the saved model says."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from proprio.experiments.hybrid import Backbone, resolve_backbone, train_from_config, training_config
from proprio.learning.evaluation import predict_windowed
from proprio.learning.models import ARCHS, HybridModel, ModelConfig, load_model
from proprio.recording import Recording

torch.set_num_threads(1)
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
LWR, TX40 = SHARED / "kuka_lwr4", SHARED / "staubli_tx40"


def _small(arch: str) -> ModelConfig:
    return ModelConfig(arch=arch, n_joints=3, window=10, mlp_hidden=8, lstm_hidden=6, tf_d_model=8, tf_heads=2,
                       tf_layers=1, tf_ff=16)


@pytest.mark.parametrize("arch", ARCHS)
def test_zero_output_makes_exactly_the_backbone_on_the_chosen_joints(arch):
    torch.manual_seed(0)
    model = HybridModel(_small(arch)).eval()
    x = torch.randn(2, 10, 15)
    with torch.no_grad():
        torch.testing.assert_close(model(x), x[..., :3], rtol=0, atol=0)      # fresh: exactly τ_RBD
        for p in model.net.parameters():
            p.copy_(0.3 * torch.randn_like(p))
        before = model(x)
        assert not torch.allclose(before, x[..., :3])
        if model.per_joint_output:
            model.zero_output([1])
            after = model(x)
            torch.testing.assert_close(after[..., 1], x[..., 1], rtol=0, atol=0)
            torch.testing.assert_close(after[..., [0, 2]], before[..., [0, 2]], rtol=0, atol=0)
        else:
            with pytest.raises(ValueError, match="only all joints"):
                model.zero_output([1])
            model.zero_output()
            torch.testing.assert_close(model(x), x[..., :3], rtol=0, atol=0)



def test_a_joint_keeps_its_residual_only_where_its_validation_gain_is_significant():
    """Per validation window the residual's MSE minus the backbone's: a joint keeps its residual only where their
    mean lies more than FALLBACK_Z standard errors below zero (a 1 % gain on a few scattered windows does not count)."""
    from proprio.learning.training import FALLBACK_Z, insignificant_joints
    base = torch.ones(12, 3, dtype=torch.float64)
    wobble = 0.1 * torch.tensor([1.0, -1.0] * 6, dtype=torch.float64)
    model = torch.stack([0.5 + 0.01 * wobble, 0.99 + wobble, 1.0 + 0.0 * wobble], dim=1)
    # joint 1: 50 % lower on every window; joint 2: 1 % lower on average, ±10 % per window (z ≈ 0.33); joint 3: equal
    assert FALLBACK_Z == pytest.approx(1.645)
    assert insignificant_joints(model, base) == [1, 2]
    assert insignificant_joints(model, base, z=0.2) == [2]          # a lower threshold takes the 1 % for a gain
    assert insignificant_joints(model[:1], base[:1]) == [1, 2]      # one window: below the backbone or not

def _noise_recording(seed: int, n: int = 2400, rate: float = 150.0) -> Recording:
    """τ = τ_RBD + white noise: nothing a residual could learn."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    w = rng.uniform(0.3, 1.0, 7)
    q = 0.5 * np.sin(np.outer(t, w))
    return Recording(t=t, q=q, tau=3 * np.sin(q) + rng.normal(0, 0.1, q.shape), meta={"rate_hz": rate})


def _toy(q, qd, qdd):
    return 3 * np.sin(q)


def test_a_residual_that_cannot_help_falls_back_to_the_backbone(tmp_path):
    from proprio.description import load_robot
    from proprio.experiments.hybrid import prepare_split
    from proprio.learning.datasets import DataConfig
    desc = load_robot("iiwa14_identified")
    backbone = Backbone("toy", desc, _toy)
    cfg = {"model": {"arch": "lstm2_fcl", "lstm_hidden": 8}, "data": {"window": 20, "val_fraction": 0.3},
           "train": {"max_epochs": 4, "batch_size": 4, "lr": 0.3, "seed": 0}}   # lr far too high: it only overfits
    recs = [_noise_recording(s) for s in (0, 1)]
    split = prepare_split(recs, backbone, DataConfig.from_dict(cfg["data"]), [_noise_recording(2)])
    model, result, rows = train_from_config(training_config(cfg, "test"), recs, backbone, tmp_path / "m.pt",
                                            progress=False, split=split)
    saved, extra = load_model(tmp_path / "m.pt")
    assert result.fallback == "all" and extra["fallback"] == "all" and result.best_epoch == -1
    assert "residual not kept" in result.fallback_line()
    pred = predict_windowed(saved, split.test.features)
    np.testing.assert_array_equal(pred, split.test.features[..., :7].astype(np.float32))   # τ_RBD (float32 model)
    assert rows[1].test.mean() <= rows[0].test.mean()


def _held_out_check(recs, tests, backbone, cfg, tmp_path) -> None:
    _, result, rows = train_from_config(training_config(cfg, "test"), recs, backbone, tmp_path / "m.pt",
                                        test_recs=tests, progress=False)
    saved, extra = load_model(tmp_path / "m.pt")
    assert extra["fallback"] == result.fallback and np.isfinite(extra["backbone_val"])
    rbd, hybrid = rows[0].test, rows[1].test
    back = np.zeros(rbd.shape, dtype=bool)
    back[list(range(len(rbd))) if result.fallback == "all" else result.fallback] = True
    # where the residual is kept the held-out error is not above the backbone's; where it fell back it is the
    # backbone's (to the float32 model's rounding)
    assert np.all(hybrid[~back] <= rbd[~back]), (hybrid, rbd, result.fallback)
    np.testing.assert_allclose(hybrid[back], rbd[back], rtol=1e-6)


@pytest.mark.skipif(not LWR.is_dir(), reason="../shared/data/kuka_lwr4 not present")
def test_lwr4_saved_hybrid_is_not_worse_than_its_backbone_on_the_validation_file(tmp_path):
    from proprio.recording import load_recording
    recs = [load_recording(LWR / f"measurements_{i}.npz") for i in (2, 3)]
    cfg = {"model": {"arch": "lstm2_fcl", "lstm_hidden": 12}, "data": {"window": 50, "trim_s": 0.5,
                                                                          "val_fraction": 0.2},
           "train": {"max_epochs": 6, "batch_size": 8, "seed": 0}}
    _held_out_check(recs, [load_recording(LWR / "measurements_1.npz")], resolve_backbone(str(LWR)), cfg, tmp_path)


@pytest.mark.skipif(not TX40.is_dir(), reason="../shared/data/staubli_tx40 not present")
def test_tx40_saved_hybrid_is_not_worse_than_its_backbone_on_the_last_seconds(tmp_path):
    from proprio.importer import import_recording
    rec = import_recording(Path(__file__).resolve().parents[1] / "proprio" / "configs" / "import_tx40.yaml",
                           data_dir=TX40)
    split = int(np.searchsorted(rec.t, rec.t[0] + 6.0))                  # train 0–6 s, test 6–9 s
    cfg = {"model": {"arch": "lstm2_fcl", "lstm_hidden": 12},
           "data": {"decimate": 25, "window": 20, "cutoff_hz": 100.0, "val_fraction": 0.2, "trim_s": 0.02},
           "train": {"max_epochs": 6, "batch_size": 4, "seed": 0}}
    _held_out_check([rec.slice(0, split)], [rec.slice(split, rec.n_samples)], resolve_backbone("staubli_tx40"),
                    cfg, tmp_path)
