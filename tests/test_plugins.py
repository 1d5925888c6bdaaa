"""User-defined effects (plugins, README "Your own effect"): resolved by dotted path once the user consented (an
entry point, --allow-plugin, register_plugin), simulated by the twin (link side in the joint drive, sensor side in
the torque sensor), named by the diagnosis when the model lacks them; a config alone never imports code."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from importlib import resources
from pydrake.trajectories import PiecewisePolynomial

from proprio.description import load_robot
from proprio.diagnosis.benchmark_cases import rfma_like_motion
from proprio.diagnosis.data import SimModel
from proprio.diagnosis.selection import attribute
from proprio.diagrams.twin import TwinConfig, TwinConfigError, simulate_twin
from proprio.effects import EffectConfigError, JointEffect, effect_key, make_effects, register_plugin, resolve_effect
from proprio.effects.plugins import ALLOW_ENV
from proprio.effects.base import INF, diagonal_regressor
from proprio.recording import Recording
from proprio.signals import MotionSignals


class HoseSpring(JointEffect):
    """The README's example: the dress pack as a torsion spring ``k (q − q_ref)`` [N·m] (link side)."""
    name = "hose_spring"
    place = "link"
    linear = True
    parameters = {"stiffness": (0.0, -INF, INF)}           # k [N·m/rad]
    settings = {"reference": (0.0, -INF, INF)}             # q_ref [rad]

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        self._check_n(s)
        return self.stiffness * (s.q - self.reference)

    def regressor(self, s: MotionSignals) -> np.ndarray:
        self._check_n(s)
        return diagonal_regressor([s.q - self.reference])


class GaugeCrossTalk(JointEffect):
    """Sensor side: joint j's gauge reads ``c_j`` times joint j+1's transmitted torque."""
    name = "gauge_cross_talk"
    place = "sensor"
    linear = False
    parameters = {"coupling": (0.0, -1.0, 1.0)}

    def torque(self, s: MotionSignals, rng: np.random.Generator | None = None) -> np.ndarray:
        nxt = np.zeros_like(s.tau)
        nxt[:, :-1] = s.tau[:, 1:]
        return self.coupling * nxt


class MotorSidePlugin(HoseSpring):
    name = "motor_plugin"
    place = "motor"


class NotAnEffect:
    name = "nothing"


SPRING = register_plugin(HoseSpring)
CROSS_TALK = register_plugin(GaugeCrossTalk)
K1 = 3.0                                                      # N·m/rad on joint 1


def twin_config(effects: dict) -> TwinConfig:
    data = yaml.safe_load(resources.files("proprio.configs").joinpath("iiwa14_twin.yaml").read_text())
    data["effects"] = effects
    data["logger"] = {"rate_hz": 200, "channels": ["q", "tau"], "stamp_jitter_ms": 0.0, "dropout_prob": 0.0}
    return TwinConfig.from_dict(data, "test")


def test_resolve_effect_and_its_errors(monkeypatch):
    assert resolve_effect("hysteresis").name == "hysteresis"
    assert resolve_effect(SPRING) is HoseSpring and effect_key(HoseSpring) == SPRING == f"{__name__}:HoseSpring"
    assert resolve_effect("proprio.effects.open_world:CableSpring").place == "link"     # shipped: no consent needed
    with pytest.raises(EffectConfigError, match="not registered.*--allow-plugin"):
        resolve_effect(f"{__name__}:Missing")                  # the module is even imported already: still refused
    with pytest.raises(EffectConfigError, match="absolute path"):
        resolve_effect(".relative:Spring")
    monkeypatch.setenv(ALLOW_ENV, ",".join(f"{__name__}:{c}" for c in ("Missing", "NotAnEffect", "MotorSidePlugin"))
                       + ",no_such_package_xyz.effects:Spring")
    with pytest.raises(EffectConfigError, match="cannot be imported"):
        resolve_effect("no_such_package_xyz.effects:Spring")
    with pytest.raises(EffectConfigError, match="no attribute 'Missing'"):
        resolve_effect(f"{__name__}:Missing")
    with pytest.raises(EffectConfigError, match="not a subclass of proprio.effects.JointEffect"):
        resolve_effect(f"{__name__}:NotAnEffect")
    with pytest.raises(EffectConfigError, match="place = 'motor'"):
        resolve_effect(f"{__name__}:MotorSidePlugin")
    with pytest.raises(EffectConfigError, match="unknown joint effect"):
        make_effects({"hose_spring": {}}, 7)
    with pytest.raises(TwinConfigError, match="cannot be imported"):
        twin_config({"no_such_package_xyz.effects:Spring": {}})


def test_plugins_act_in_the_twin_and_are_logged_as_truth():
    k = np.zeros(7)
    k[0] = K1
    c = np.zeros(7)
    c[2] = 0.05
    cfg = twin_config({SPRING: {"stiffness": k.tolist()}, CROSS_TALK: {"coupling": c.tolist()}})
    t = np.linspace(0.0, 2.0, 5)
    q = np.array([0.1, 0.5, -0.2, -1.2, 0.3, 0.7, 0.2]) + np.outer([0, 0.4, -0.3, 0.2, 0], np.ones(7))
    rec = simulate_twin(cfg, PiecewisePolynomial.CubicShapePreserving(t, q.T, True), progress=False)
    tr = rec.truth
    # link side: the drive applied it, so the transmitted τ_J carries it on top of the rigid body
    np.testing.assert_allclose(tr["tau_hose_spring"][:, 0], K1 * tr["q_true"][:, 0], atol=1e-12)
    np.testing.assert_allclose(tr["tau_J_true"] - tr["tau_rbd"], tr["tau_hose_spring"], atol=1e-6)
    assert np.ptp(tr["tau_hose_spring"][:, 0]) > 0.5 * K1 * 0.4
    # sensor side: the measured τ = τ_J + cross-talk of the next joint's τ_J (no noise effect configured)
    np.testing.assert_allclose(tr["tau_gauge_cross_talk"][:, 2], 0.05 * tr["tau_J_true"][:, 3], atol=1e-12)
    np.testing.assert_allclose(rec.tau, tr["tau_J_true"] + tr["tau_gauge_cross_talk"], atol=1e-9)
    assert set(rec.meta["effects"]) == {SPRING, CROSS_TALK}
    assert [e.name for e in make_effects(rec.meta["effects"], 7)] == ["hose_spring", "gauge_cross_talk"]


def _twin_recording(cfg: TwinConfig, seed: int) -> Recording:
    """20 s of the benchmark's RFMA-like motion played by the twin (200 Hz log: q and τ only)."""
    t, q, qd, _, _ = rfma_like_motion(cfg.robot, seed, 20.0, rate_hz=50.0)
    rec = simulate_twin(cfg, PiecewisePolynomial.CubicHermite(t, q.T, qd.T), progress=False)
    return Recording(t=rec.t, q=rec.q, tau=rec.tau, meta={"robot": cfg.robot.name, "source": "test"})


def test_diagnosis_names_a_withheld_plugin_effect():
    k = np.zeros(7)
    k[0] = K1
    cfg = twin_config({SPRING: {"stiffness": k.tolist()}, "torque_noise": {"std": 0.05}})
    recs = [_twin_recording(cfg, seed) for seed in (1, 2, 3)]
    model = SimModel(load_robot("iiwa14_identified").without_friction(), tuple(make_effects({"torque_noise": {
        "std": 0.05}}, 7)))
    att = attribute(model, recs[:2], recs[2:], plugins=[SPRING])
    assert "hose_spring" in att.candidates
    assert att.top(1) == ["hose_spring"]
    fitted = att.steps[0].params["hose_spring"][0]
    assert abs(fitted[0] - K1) < 0.1 * K1 and np.all(np.abs(fitted[1:]) < 0.1 * K1)
    assert att.steps[0].rmse_after[0] < 0.2 * att.rmse_before[0]
    # the same plugin in the model: nothing left to name
    with_it = SimModel(model.robot, model.effects + (HoseSpring(7, stiffness=k),))
    assert not attribute(with_it, recs[:2], recs[2:]).physical_steps


def test_cli_names_a_bad_plugin_in_one_line(tmp_path, capsys):
    from proprio.cli import main
    from proprio.dynamics import inverse_dynamics
    from proprio.recording import save_recording

    robot = load_robot("iiwa14_nominal")
    paths = []
    for seed in (1, 2):
        t, q, qd, qdd, _ = rfma_like_motion(robot, seed, 8.0)
        rec = Recording(t=t, q=q, tau=inverse_dynamics(robot, q, qd, qdd), meta={"robot": robot.name})
        paths.append(str(save_recording(rec, tmp_path / f"r{seed}.npz")))
    base = ["diagnose", "--model", "iiwa14_nominal", "--train", paths[0], "--holdout", paths[1], "--out",
            str(tmp_path / "d")]
    for extra, expected in ((["--candidate", "no_such_package_xyz:Spring"], "--candidate: .*cannot be imported"),
                            (["--candidate", f"{__name__}:NotAnEffect"], "not a subclass"),
                            (["--effects", f"{__name__}:MotorSidePlugin"], "--effects: .*place = 'motor'")):
        assert main(base + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.search(expected, err[0]), err
