"""Typed configs (issue 21, item 4): every YAML the app reads loads strictly into dataclasses; a misspelt key is an
error naming the file, the key path and the nearest valid key; wrong types and lengths name the field; the shipped
configs load; ``proprio dataset --log-rate`` sets the logger's rate."""
from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import yaml

from proprio.cli import UserError
from proprio.cli.diagnose import _effects_config
from proprio.diagrams.twin import TwinConfigError, load_twin_config
from proprio.experiments.hybrid import load_config
from proprio.identification.excitation import load_excitation_config, load_shipped_excitation
from proprio.systems.rfma import RfmaError, load_rfma_config
from proprio.typed_yaml import ConfigError

CONFIGS = resources.files("proprio.configs")


def _shipped(name: str) -> dict[str, Any]:
    return yaml.safe_load(CONFIGS.joinpath(name).read_text())


def _write(tmp_path: Path, name: str, data: dict[str, Any]) -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _twin_with(mutate: Callable[[dict[str, Any]], None]) -> Callable[[Path], Path]:
    def make(tmp_path: Path) -> Path:
        data = _shipped("iiwa14_twin.yaml")
        mutate(data)
        return _write(tmp_path, "my_twin.yaml", data)
    return make


def _rename(section: dict[str, Any], old: str, new: str) -> None:
    section[new] = section.pop(old)


def _load_twin(path: Path) -> None:
    load_twin_config(path)


def _load_patch(path: Path) -> None:
    load_twin_config("iiwa14_nominal_twin", patch=path)


def _patch_file(tmp_path: Path, **entries: Any) -> Path:
    base = load_twin_config("iiwa14_nominal_twin")
    return _write(tmp_path, "twin_patch.yaml", {"patch_for": {"robot": base.robot.name, "joints": base.robot.n},
                                                **entries})


def _rfma(tmp_path: Path) -> Path:
    data = _shipped("rfma.yaml")
    _rename(data, "scaffolds", "scafolds")
    return _write(tmp_path, "my_rfma.yaml", data)


def _training(tmp_path: Path) -> Path:
    data = _shipped("train_lstm2_fcl.yaml")
    _rename(data["model"], "lstm_hidden", "lstm_hiden")
    return _write(tmp_path, "my_train.yaml", data)


def _effects_cfg(tmp_path: Path) -> Path:
    return _write(tmp_path, "effects.yaml", {"effects": {"hysteresis": {"saturaton": 0.3}}})


# (kind, make the file, load it, expected error type, misspelt key path, nearest valid key)
CASES = [
    ("twin", _twin_with(lambda d: _rename(d, "session_time_s", "sesion_time_s") if "session_time_s" in d
                        else d.update(sesion_time_s=1.0)), _load_twin, TwinConfigError,
     "my_twin.yaml: sesion_time_s", "session_time_s"),
    ("logger", _twin_with(lambda d: _rename(d["logger"], "dropout_prob", "dropout_prop")), _load_twin,
     TwinConfigError, "my_twin.yaml: logger.dropout_prop", "dropout_prob"),
    ("controller", _twin_with(lambda d: _rename(d["controller"], "payload_model", "payload_modle")), _load_twin,
     TwinConfigError, "my_twin.yaml: controller.payload_modle", "payload_model"),
    ("drive", _twin_with(lambda d: _rename(d["drive"], "motor_inertia", "motor_inertai")), _load_twin,
     TwinConfigError, "my_twin.yaml: drive.motor_inertai", "motor_inertia"),
    ("effect name", _twin_with(lambda d: _rename(d["effects"], "hysteresis", "hysterisis")), _load_twin,
     TwinConfigError, "my_twin.yaml: effects.hysterisis", "hysteresis"),
    ("effect parameter", _twin_with(lambda d: _rename(d["effects"]["hysteresis"], "saturation", "saturaton")),
     _load_twin, TwinConfigError, "my_twin.yaml: effects.hysteresis.saturaton", "saturation"),
    ("payload", _twin_with(lambda d: d.update(payload={"mass": 1.0, "com": [0, 0, 0.1]})), _load_twin,
     TwinConfigError, "my_twin.yaml: payload.com", "com_flange"),
    ("rfma", _rfma, load_rfma_config, RfmaError, "my_rfma.yaml: scafolds", "scaffolds"),
    ("training", _training, load_config, ConfigError, "my_train.yaml: model: lstm_hiden", "lstm_hidden"),
    ("patch", lambda tmp: _patch_file(tmp, payloda={"mass": 1.0}), _load_patch, TwinConfigError,
     "twin_patch.yaml: payloda", "payload"),
    ("patch effect", lambda tmp: _patch_file(tmp, effects={"stribeck": {"statik": 0.1}}), _load_patch,
     TwinConfigError, "twin_patch.yaml: effects.stribeck.statik", "static"),
    ("effects-config", _effects_cfg, lambda p: _effects_config(p, 7), UserError,
     "effects.yaml: effects.hysteresis.saturaton", "saturation"),
]


@pytest.mark.parametrize("kind, make, load, error, key_path, nearest", CASES, ids=[c[0] for c in CASES])
def test_a_misspelt_key_names_the_file_the_key_path_and_the_nearest_key(kind, make, load, error, key_path,
                                                                        nearest, tmp_path):
    path = make(tmp_path)
    with pytest.raises(error) as info:
        load(path)
    message = str(info.value)
    assert key_path in message, message
    assert f"did you mean '{nearest}'" in message, message


def test_a_misspelt_excitation_key_names_the_nearest_key():
    with pytest.raises(ConfigError, match=re.escape("excitation.yaml: optimisation.start: unknown key; did you "
                                                    "mean 'starts'")):
        load_excitation_config({"optimisation": {"start": 2}})
    with pytest.raises(ConfigError, match="optimization: unknown key; did you mean 'optimisation'"):
        load_excitation_config({"optimization": {"starts": 2}})


def test_the_excitation_cost_takes_the_one_friction_smoothing(monkeypatch):
    """No second Coulomb smoothing in the excitation config: the old key is an error, and the optimiser's cost
    follows :data:`proprio.friction_law.SMOOTH_VELOCITY` (a change there changes the cost)."""
    from proprio import friction_law
    from proprio.description import load_robot
    from proprio.identification.base_parameters import base_parameters
    from proprio.identification.excitation import _CondCost

    with pytest.raises(ConfigError, match="optimisation.coulomb_velocity_scale: unknown key"):
        load_excitation_config({"optimisation": {"coulomb_velocity_scale": 0.02}})
    robot = load_robot("iiwa14_nominal")
    cost = _CondCost(robot, base_parameters(robot), np.linspace(0, 20, 30, endpoint=False), 5, 0.1 * np.pi)
    x = np.random.default_rng(0).uniform(-0.3, 0.3, 70)
    before = cost.value_and_gradient(x)[0]
    monkeypatch.setattr(friction_law, "SMOOTH_VELOCITY", 0.5)
    assert abs(cost.value_and_gradient(x)[0] - before) > 1e-6 * before


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["controller"].update(kp="stiff"), "controller.kp"),
    (lambda d: d["controller"].update(kd=[60, 60]), "controller.kd"),
    (lambda d: d["effects"]["torque_noise"].update(std=[0.1, 0.2, 0.3]), "torque_noise.std"),
    (lambda d: d["effects"]["hysteresis"].update(saturation_travel_deg="six"), "hysteresis.saturation_travel_deg"),
    (lambda d: d["drive"].update(motor_viscous=[1.0] * 8), "drive.motor_viscous"),
    (lambda d: d.update(payload={"mass": 1.0, "com_flange": [0, 0.1]}), "payload.com_flange"),
    (lambda d: d.update(payload={"mass": "heavy"}), "payload.mass"),
    (lambda d: d["logger"].update(rate_hz="fast"), "logger.rate_hz"),
    (lambda d: d.update(seed="seven"), "seed"),
], ids=["word gain", "short gains", "long effect list", "word effect", "long drive list", "short com", "word mass",
        "word rate", "word seed"])
def test_wrong_types_and_lengths_name_the_field(mutate, field, tmp_path):
    path = _twin_with(mutate)(tmp_path)
    with pytest.raises(TwinConfigError, match=re.escape(field)):
        load_twin_config(path)


def test_physics_checks_keep_their_messages(tmp_path):
    path = _twin_with(lambda d: d["logger"].update(rate_hz=5000))(tmp_path)
    with pytest.raises(TwinConfigError, match=re.escape("logger.rate_hz must be in (0, 1/time_step = 1000] Hz")):
        load_twin_config(path)
    path = _twin_with(lambda d: d["effects"]["hysteresis"].update(saturation=-1.0))(tmp_path)
    with pytest.raises(TwinConfigError, match=r"hysteresis.saturation = -1 is outside"):
        load_twin_config(path)


def test_a_patch_is_an_overlay_on_its_base(tmp_path):
    base = load_twin_config("iiwa14_nominal_twin")
    path = _patch_file(tmp_path, effects={"stribeck": {"static": 0.1}},
                       payload={"mass": 1.5, "com_flange": [0.0, 0.0, 0.05]})
    patched = load_twin_config("iiwa14_nominal_twin", patch=path)
    assert [e.name for e in patched.effects] == [e.name for e in base.effects] + ["stribeck"]
    assert np.allclose(patched.effect("stribeck").static, 0.1)
    assert patched.payload.mass == 1.5 and patched.payload.com_flange == (0.0, 0.0, 0.05)
    assert np.array_equal(patched.kp, base.kp) and patched.logger == base.logger


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIGS.iterdir() if p.name.endswith(".yaml")))
def test_every_shipped_config_loads(name):
    if name.startswith("train_"):                # each section in its dataclass, with the file's values
        cfg, raw = load_config(name), _shipped(name)
        for section in ("model", "data", "train"):
            for key, value in (raw.get(section) or {}).items():
                got = getattr(getattr(cfg, section), key)
                assert got == (tuple(value) if isinstance(got, tuple) else value), (section, key)
        assert cfg.search == (raw.get("search") or {})
    elif name.endswith("_twin.yaml"):
        cfg = load_twin_config(name)
        assert cfg.robot.n == cfg.kp.size
    elif name == "rfma.yaml":
        assert load_rfma_config().scaffolds == _shipped(name)["scaffolds"]
    elif name == "excitation.yaml":
        assert load_excitation_config().fourier.harmonics == _shipped(name)["fourier"]["harmonics"]
    elif name.endswith("_excitation.yaml"):
        traj, info = load_shipped_excitation(name[:-5])
        assert traj.a.shape == traj.b.shape and info["cond"] > 0
    elif name.startswith("import_"):
        from proprio.importer import load_mapping
        assert load_mapping(CONFIGS / name).raw["tau_kind"] in ("link_sensor", "drive")
    else:
        pytest.fail(f"{name}: a shipped config no test loads")


def test_dataset_log_rate_writes_recordings_at_that_rate(tmp_path):
    from proprio.cli import main
    from proprio.recording import load_recording

    out = tmp_path / "ds"
    assert main(["dataset", "--twin", "iiwa14_nominal_twin", "--seeds", "3", "--scaffolds", "1", "--seconds", "1",
                 "--log-rate", "200", "--quiet", "--out", str(out)]) == 0
    rec = load_recording(next(out.glob("rfma_s3_*.npz")))
    assert rec.meta["rate_hz"] == 200
    assert np.median(np.diff(rec.t)) == pytest.approx(5e-3, abs=2e-4)
    assert rec.t.size == pytest.approx(200 * (rec.t[-1] - rec.t[0]) + 1, abs=1)     # no sample lost, none extra


def test_the_cli_reports_a_misspelt_key_in_one_line(tmp_path, capsys):
    from proprio.cli import main

    path = _rfma(tmp_path)
    assert main(["trajectory", "rfma", "--config", str(path), "--out", str(tmp_path / "t.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "scafolds: unknown key; did you mean 'scaffolds'?" in err, err
    assert not (tmp_path / "t.npz").exists()
