"""Issue 36, "never throw the answer away": on a drive-torque arm several named effects each correct the robot
description (rigid body, rotor inertia, motor friction); the twin patch merges them into ONE corrected description
(:func:`proprio.diagnosis.patch.merge_entries`), a true conflict is said, never raised, and the patched twin
reproduces the held-out data better than the base twin."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from proprio.diagnosis.data import SimModel
from proprio.diagnosis.patch import PatchEntry, merge_entries
from proprio.drive_description import drive_from_dict
from proprio.gap_benchmark.case_data import twin_recordings
from proprio.gap_benchmark.cases import BenchmarkCase
from proprio.gap_benchmark.drive import DRIVE_LOGGERS, drive_case_config


def _robot_with(robot, **drive_changes):
    """``robot`` (a drive arm's description) with drive-block entries replaced (``rotor_inertia=[...]``...)."""
    block = robot.to_dict()["drive"]
    block.update(drive_changes)
    return dataclasses.replace(robot, drive=drive_from_dict(block, robot.n))


def test_merge_of_description_fragments_leaf_by_leaf_and_conflicts_said():
    """Three fragments, each the full description of the same base with its own change: merged, every change is in
    the one robot; a fourth changing an already-changed leaf to another value is a conflict line, not an error."""
    _, robot, _ = drive_case_config(BenchmarkCase("c", ("coupled_motor_friction",), 1.0, 5, twin=True,
                                                  logger=DRIVE_LOGGERS[100.0]))
    model = SimModel(robot)
    d = robot.to_dict()["drive"]
    inertia = (2.0 * np.asarray(d["rotor_inertia"])).tolist()
    viscous = (1.5 * np.asarray(d["motor_friction"]["viscous"])).tolist()
    heavier = dataclasses.replace(robot.links[2], mass=robot.links[2].mass + 1.0)
    frag = lambda r: {"robot": {**r.to_dict(), "name": robot.name}}  # noqa: E731
    entries = [PatchEntry("rigid_body", frag(robot.with_inertials(robot.links[:2] + (heavier,) + robot.links[3:])), []),
               PatchEntry("rotor_inertia", frag(_robot_with(robot, rotor_inertia=inertia)), []),
               PatchEntry("motor_friction", frag(_robot_with(robot, motor_friction={**d["motor_friction"],
                                                                                      "viscous": viscous})), []),
               PatchEntry("viscous_coulomb", {"effects": {"viscous_coulomb": {"viscous": [0.1] * robot.n}}}, [])]
    merged = merge_entries(entries, model)
    assert merged.unmerged == []
    out = merged.patch["robot"]
    assert out["links"][2]["mass"] == pytest.approx(robot.links[2].mass + 1.0)
    assert out["drive"]["rotor_inertia"] == pytest.approx(inertia)
    assert out["drive"]["motor_friction"]["viscous"] == pytest.approx(viscous)
    assert out["drive"]["motor_friction"]["coulomb"] == pytest.approx(d["motor_friction"]["coulomb"])
    assert merged.patch["effects"] == {"viscous_coulomb": {"viscous": [0.1] * robot.n}}
    again = entries + [PatchEntry("drive_offset", frag(_robot_with(robot, rotor_inertia=d["rotor_inertia"][:6]
                                                                   + [1.0])), [])]
    merged = merge_entries(again, model)
    assert len(merged.unmerged) == 1 and "rotor_inertia" in merged.unmerged[0] and "drive_offset" in merged.unmerged[0]
    assert merged.patch["robot"]["drive"]["rotor_inertia"] == pytest.approx(inertia)       # the first one's kept


def test_rigid_body_rotor_inertia_and_motor_friction_named_patched_and_replayed(tmp_path):
    """A coupled drive-arm twin whose model lacks the shared motor's friction, half the rotor inertia and has a link
    mass wrong: diagnosed with those three candidates, all named; the run writes its report and ONE robot patch
    holding all three corrections; replayed through the twin, the patched twin is closer to the held-out data than
    the base twin (issue 36, deliver 1 — before, the patch raised "rotor_inertia sets 'robot' a second time")."""
    from proprio.diagnosis import diagnose
    from proprio.diagrams.twin_config import TwinConfig

    case = BenchmarkCase("drive:patch-merge/100Hz", ("coupled_motor_friction",), 1.0, 17, twin=True,
                         logger=DRIVE_LOGGERS[100.0])
    config, model_robot, params = drive_case_config(case)
    recs = twin_recordings(case, [config] * 3, meta={"tau_kind": "drive"})
    d = model_robot.to_dict()["drive"]
    links = list(model_robot.links)
    links[1] = dataclasses.replace(links[1], mass=1.25 * links[1].mass)
    model_robot = _robot_with(model_robot.with_inertials(links),
                              rotor_inertia=(0.5 * np.asarray(d["rotor_inertia"])).tolist())
    from proprio.effects import EFFECTS

    model = SimModel(model_robot, (EFFECTS["viscous_coulomb"].from_config(params["viscous_coulomb"], model_robot.n),))
    raw = {k: v for k, v in config.raw.items() if k not in ("drive", "effects")}
    raw.update(name="drive_arm_model", robot={**model_robot.to_dict(), "name": model_robot.name}, payload=None,
               logger={**raw["logger"], **dict(case.logger)},
               effects={"viscous_coulomb": {k: np.asarray(v).tolist() for k, v in params["viscous_coulomb"].items()}})
    base = TwinConfig.from_dict(raw, "test base twin")
    out = tmp_path / "diag"
    diag = diagnose(model, recs[:2], recs[2:], out, candidates=["rigid_body", "rotor_inertia", "motor_friction"],
                    twin=base)
    named = {s.name for s in diag.attribution.physical_steps}
    assert named == {"rigid_body", "rotor_inertia", "motor_friction"}, named
    assert not diag.failures, diag.failures
    patch = yaml.safe_load((out / "twin_patch.yaml").read_text())
    robot = yaml.safe_load((out / patch["robot"]).read_text())
    assert robot["drive"]["rotor_inertia"] != pytest.approx(d["rotor_inertia"], rel=0.01)   # corrected upward
    assert np.sum(robot["drive"]["rotor_inertia"]) > 0.5 * np.sum(d["rotor_inertia"]) * 1.2
    assert robot["links"][1]["mass"] != pytest.approx(model_robot.links[1].mass, rel=1e-6)  # inertials corrected
    assert robot["drive"]["motor_friction"] != model_robot.to_dict()["drive"]["motor_friction"]
    gap = diag.replay
    assert gap.total(gap.rms_after) < 0.8 * gap.total(gap.rms_before), gap.text()
    assert (out / "report.html").is_file() and (out / "diagnosis.json").is_file()
