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
from proprio.gap_benchmark.case_data import rfma_like_motion
from proprio.diagnosis.data import SimModel
from proprio.diagnosis.selection.forward import attribute
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


def _twin_recording(cfg: TwinConfig, seed: int, seconds: float) -> Recording:
    """``seconds`` of the benchmark's RFMA-like motion played by the twin (200 Hz log: q and τ only)."""
    t, q, qd, _, _ = rfma_like_motion(cfg.robot, seed, seconds, rate_hz=50.0)
    rec = simulate_twin(cfg, PiecewisePolynomial.CubicHermite(t, q.T, qd.T), progress=False)
    return Recording(t=rec.t, q=rec.q, tau=rec.tau, meta={"robot": cfg.robot.name, "source": "test"})


def test_diagnosis_names_a_withheld_plugin_effect(full):
    """3 twin runs of 20 s (``--full``) or 10 s: at 10 s the spring is still fitted to 0.1 % (bound 10 %) and removes
    98 % of joint 1's held-out RMSE (bound 80 %)."""
    k = np.zeros(7)
    k[0] = K1
    cfg = twin_config({SPRING: {"stiffness": k.tolist()}, "torque_noise": {"std": 0.05}})
    recs = [_twin_recording(cfg, seed, 20.0 if full else 10.0) for seed in (1, 2, 3)]
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


# --------------------------------------------------------------------------------------------------------------------
# consent: a config names a plugin, it never imports one (issue 26)
# --------------------------------------------------------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[1]
EVIL = '''
from pathlib import Path
Path({marker!r}).write_text("imported")
from proprio.effects import JointEffect
class Boom(JointEffect):
    name = "boom"
    place = "link"
    linear = False
    parameters = {{}}
    def torque(self, s, rng=None):
        return 0 * s.q
'''


@pytest.fixture(autouse=True)
def _no_leaked_consent(monkeypatch):
    """``--allow-plugin`` writes the allow-list into the environment: each test starts (and ends) without one."""
    monkeypatch.delenv(ALLOW_ENV, raising=False)


def _hostile_files(tmp_path: Path, module: str) -> tuple[Path, Path, Path, Path]:
    """A module that writes a marker at import, a twin YAML and a twin_patch.yaml naming it, beside it."""
    marker = tmp_path / "marker.txt"
    (tmp_path / f"{module}.py").write_text(EVIL.format(marker=str(marker)))
    twin = tmp_path / "twin.yaml"
    twin.write_text(yaml.safe_dump({"name": "evil", "robot": "iiwa14_identified", "effects": {f"{module}:Boom": {}}}))
    patch = tmp_path / "twin_patch.yaml"
    patch.write_text(yaml.safe_dump({"patch_for": {"robot": "iiwa14_identified", "joints": 7},
                                     "effects": {f"{module}:Boom": {}}}))
    return marker, twin, patch, tmp_path / "out.npz"


@pytest.mark.parametrize("which", ["twin", "patch"])
def test_a_config_cannot_import_code_in_process(tmp_path, monkeypatch, capsys, which):
    from proprio.cli import main

    module = f"evil_{which}_inproc"
    marker, twin, patch, out = _hostile_files(tmp_path, module)
    monkeypatch.syspath_prepend(str(tmp_path))                     # importable: only consent stands in the way
    monkeypatch.chdir(tmp_path)
    args = ["simulate", "--trajectory", "none.npz", "--out", str(out)]
    args += ["--twin", str(twin)] if which == "twin" else ["--patch", str(patch)]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not registered" in err[0] and f"--allow-plugin {module}:Boom" in err[0], err
    assert not marker.exists() and not out.exists() and module not in sys.modules
    # the same file with the user's consent: the module is imported (the marker proves this test can fail)
    assert main(args + ["--allow-plugin", f"{module}:Boom"]) == 2          # then --trajectory none.npz is missing
    assert "--trajectory" in capsys.readouterr().err and marker.exists()


@pytest.mark.parametrize("which", ["twin", "patch"])
def test_a_config_cannot_import_code_with_python_m(tmp_path, which):
    """``python -m proprio`` from the folder holding the .py: the working directory is not a plugin source."""
    marker, twin, patch, out = _hostile_files(tmp_path, "evil_mod")
    args = ["--twin", twin.name] if which == "twin" else ["--patch", patch.name]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop(ALLOW_ENV, None)
    for extra in ([], ["--allow-plugin", "evil_mod:Boom"]):      # even allowed, the cwd's module is not importable
        proc = subprocess.run([sys.executable, "-m", "proprio", "simulate", *args, "--trajectory", "none.npz",
                               "--out", out.name, *extra], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("proprio: error:") and "evil_mod:Boom" in lines[0], lines
        assert "Traceback" not in proc.stderr and not marker.exists() and not out.exists()


def test_an_entry_point_registers_a_plugin(tmp_path, monkeypatch):
    """A package that declares ``[project.entry-points."proprio.effects"]`` (here: its installed dist-info) is usable
    by name in a config without any flag."""
    (tmp_path / "hose_pkg.py").write_text(
        "import numpy as np\nfrom proprio.effects import JointEffect\n"
        "class Hose(JointEffect):\n    name = 'hose'\n    place = 'link'\n    linear = False\n"
        "    parameters = {'stiffness': (0.0, -1e9, 1e9)}\n"
        "    def torque(self, s, rng=None):\n        return self.stiffness * s.q\n")
    info = tmp_path / "hose_pkg-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: hose-pkg\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[proprio.effects]\nhose = hose_pkg:Hose\n")
    with pytest.raises(EffectConfigError, match="not registered"):
        make_effects({"hose_pkg:Hose": {}}, 7)
    monkeypatch.syspath_prepend(str(tmp_path))
    (effect,) = make_effects({"hose_pkg:Hose": {"stiffness": [2.0] * 7}}, 7)
    assert effect.name == "hose" and effect_key(effect) == "hose_pkg:Hose"
    q = np.full((3, 7), 0.5)
    np.testing.assert_allclose(effect.torque(MotionSignals(t=np.arange(3.0), q=q, qd=0 * q, qdd=0 * q)), 1.0)
    cfg = twin_config({"hose_pkg:Hose": {"stiffness": [2.0] * 7}})
    assert [e.name for e in cfg.effects] == ["hose"]
