"""A warm start (``proprio train --init``, the demo's pretrained residual): the saved model's weights and
normalisation are the start, they are kept when no fine-tuning epoch beats them on validation, and a model that does
not fit the config is refused with the setting that differs."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from proprio.description import load_robot
from proprio.experiments.hybrid import (Backbone, prepare_split, train_from_config, training_config,
                                        warm_start_model)
from proprio.learning.evaluation import predict_windowed
from proprio.learning.models import load_model
from proprio.recording import Recording

torch.set_num_threads(1)


def _recording(seed: int, n: int = 2400, rate: float = 150.0) -> Recording:
    """τ = τ_RBD (3 sin q) + a smooth residual 0.8 cos(2q) + small noise: a residual a network can learn."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    q = 0.8 * np.sin(np.outer(t, rng.uniform(0.3, 1.0, 7)) + rng.uniform(0, 6, 7))
    return Recording(t=t, q=q, tau=3 * np.sin(q) + 0.8 * np.cos(2 * q) + rng.normal(0, 0.02, q.shape),
                     meta={"rate_hz": rate})


def _toy(q, qd, qdd):
    return 3 * np.sin(q)


def _cfg(**train):
    return training_config({"model": {"arch": "lstm2_fcl", "lstm_hidden": 8}, "data": {"window": 20, "val_fraction": 0.25},
                            "train": {"max_epochs": 6, "batch_size": 8, "lr": 3e-3, "seed": 0, **train}}, "test")


@pytest.fixture(scope="module")
def pretrained(tmp_path_factory):
    backbone = Backbone("toy", load_robot("iiwa14_identified"), _toy)
    recs = [_recording(s) for s in (0, 1)]
    split = prepare_split(recs, backbone, _cfg().data, [_recording(2)])
    path = tmp_path_factory.mktemp("warm") / "pre.pt"
    _, result, rows = train_from_config(_cfg(), recs, backbone, path, progress=False, split=split)
    assert result.fallback != "all" and rows[1].test.mean() < 0.7 * rows[0].test.mean()   # it learned something
    return backbone, recs, split, path


def test_warm_start_keeps_the_pretrained_weights_when_fine_tuning_only_hurts(pretrained, tmp_path):
    backbone, recs, split, path = pretrained
    init, _ = load_model(path)
    # lr far too high: every fine-tuning epoch is worse than the pretrained weights, so those are what is saved
    model, result, rows = train_from_config(_cfg(max_epochs=2, lr=0.5), recs, backbone, tmp_path / "ft.pt",
                                            progress=False, split=split, init=path)
    assert result.best_epoch == -1 and result.fallback != "all"
    assert np.isfinite(result.init_val) and result.init_val < result.backbone_val
    assert all(h["val"] > result.init_val for h in result.history)
    kept = [j for j in range(7) if j not in result.fallback]
    np.testing.assert_array_equal(predict_windowed(model, split.test.features)[..., kept],
                                  predict_windowed(init, split.test.features)[..., kept])
    torch.testing.assert_close(model.x_mean, init.x_mean, rtol=0, atol=0)      # its normalisation, not the new data's
    _, extra = load_model(tmp_path / "ft.pt")
    assert extra["init"] == str(path) and extra["init_val"] == pytest.approx(result.init_val)


def test_zero_epochs_score_the_warm_start_and_keep_it_where_it_beats_the_backbone(pretrained, tmp_path):
    """``max_epochs: 0`` (the demo): no epoch runs; the pretrained weights are kept as they are (with their own
    per-joint decisions) where they beat the backbone on validation, and without a warm start the model is the
    backbone exactly."""
    backbone, recs, split, path = pretrained
    init, _ = load_model(path)
    model, result, _ = train_from_config(_cfg(max_epochs=0), recs, backbone, tmp_path / "zero.pt", progress=False,
                                         split=split, init=path)
    assert result.history == [] and result.fallback == [] and result.init_val < result.backbone_val
    np.testing.assert_array_equal(predict_windowed(model, split.test.features),
                                  predict_windowed(init, split.test.features))
    bare, result, _ = train_from_config(_cfg(max_epochs=0), recs, backbone, tmp_path / "bare.pt", progress=False,
                                        split=split)
    assert result.fallback == "all"
    np.testing.assert_allclose(predict_windowed(bare, split.test.features), split.test.features[..., :7], atol=1e-5)
    with pytest.raises(ValueError, match="max_epochs must be >= 0"):
        _cfg(max_epochs=-1)


def test_warm_start_fine_tunes_from_the_pretrained_model(pretrained, tmp_path):
    backbone, recs, split, path = pretrained
    _, warm, _ = train_from_config(_cfg(max_epochs=1), recs, backbone, tmp_path / "ft.pt", progress=False,
                                   split=split, init=path)
    _, cold, _ = train_from_config(_cfg(max_epochs=1), recs, backbone, tmp_path / "cold.pt", progress=False,
                                   split=split)
    assert warm.history[0]["val"] < 0.7 * cold.history[0]["val"]         # the first epoch starts where pretraining ended
    assert np.isnan(cold.init_val) and warm.init_val < warm.backbone_val


def test_warm_start_refuses_a_model_that_does_not_fit_the_config(pretrained):
    _, _, split, path = pretrained
    init, _ = load_model(path)
    from dataclasses import replace
    with pytest.raises(ValueError, match=r"pre\.pt.*window \(20 vs 50\)"):
        warm_start_model(path, replace(init.cfg, window=50))
    with pytest.raises(ValueError, match="rate_hz"):
        warm_start_model(path, replace(init.cfg, rate_hz=init.cfg.rate_hz * 1.1))
    assert warm_start_model(path, replace(init.cfg, rate_hz=init.cfg.rate_hz * 1.005)).cfg == init.cfg
