"""The gap benchmark's drive-torque family (:mod:`proprio.gap_benchmark.drive`): its cases, the arm and model
each case withholds from, and the drive arm's twin — whose τ is the drive torque with the diagnosis' own laws."""
from __future__ import annotations

import numpy as np
import pytest

from proprio.gap_benchmark.cases import expected_name
from proprio.gap_benchmark.drive import DRIVE_TYPES, SHARED_MOTOR, drive_case_config, drive_cases


def test_family_cases():
    quick = drive_cases(quick=True)
    # every kind at magnitude 1, load_friction at 0.5 and 1 too (it joined the quick list at both), a null case
    assert len(quick) == 2 * (len(DRIVE_TYPES) + 2)
    assert {dict(c.logger)["rate_hz"] for c in quick} == {100.0, 1000.0}
    assert all(c.twin and c.name.startswith("drive:") for c in quick)
    assert sum(not c.withheld for c in quick) == 2
    full = drive_cases()
    assert len(full) == 2 * (2 * len(DRIVE_TYPES) + 2) and len({c.name for c in full}) == len(full)


@pytest.mark.parametrize("kind", DRIVE_TYPES)
def test_each_case_withholds_its_effect_only(kind):
    case = next(c for c in drive_cases(quick=True) if c.withheld == (kind,))
    config, model, params = drive_case_config(case)
    floor, model_again, _ = drive_case_config(case, omit_withheld=True)
    arm = config.robot.drive
    assert config.robot.drive.in_tau and model.drive.in_tau and "viscous_coulomb" in params
    assert model_again == model                                   # the same model either way
    assert floor.robot.drive == model.drive                       # the floor's arm is what the model says
    differ = {k for k in ("rotor_inertia", "motor_viscous", "motor_coulomb", "offset")
              if not np.allclose(getattr(arm, k), getattr(model.drive, k))}
    want = {"rotor_inertia": {"rotor_inertia"}, "motor_friction": {"motor_viscous", "motor_coulomb"},
            "coupled_motor_friction": {"motor_viscous", "motor_coulomb"}, "drive_offset": {"offset"},
            "presliding": set(), "load_friction": set()}[kind]
    assert differ == want
    assert config.robot.drive.coupled == model.drive.coupled == (kind == "coupled_motor_friction")
    assert (config.motor_coupling is not None) == (kind == "coupled_motor_friction")   # the twin's drive couples too
    if kind == "coupled_motor_friction":                          # the shared motor's friction only
        for k in ("motor_viscous", "motor_coulomb"):
            shared = ~np.isclose(getattr(arm, k), getattr(model.drive, k))
            assert np.flatnonzero(shared).tolist() == [SHARED_MOTOR]
        assert expected_name(case) == "motor_friction"
    assert any(e.name == "presliding" for e in config.effects) == (kind == "presliding")
    assert not any(e.name == "presliding" for e in floor.effects)
    assert any(e.name == "load_friction" for e in config.effects) == (kind == "load_friction")
    assert not any(e.name == "load_friction" for e in floor.effects)


@pytest.mark.parametrize("kind", ["presliding", "coupled_motor_friction"])
def test_drive_arm_twin_senses_the_drive_laws(kind):
    """Through the twin, the drive arm's τ (less its noise) is the diagnosis' model of the arm — rigid body, rotor
    inertia (coupled: ``CᵀI_aC``), link and motor friction (coupled: ``Cᵀτ_f,m(C q̇)``), offsets
    (:class:`proprio.diagnosis.data.SimModel`) — plus the batch law of the pre-sliding friction the drive applied per
    step, on the true motion, to 1e-6 N·m; and the withheld part is what the model lacks."""
    from pydrake.trajectories import PiecewisePolynomial

    from proprio.diagnosis.data import SimModel
    from proprio.diagrams.twin import simulate_twin
    from proprio.effects import EFFECTS, PreSliding
    from proprio.signals import MotionSignals

    case = next(c for c in drive_cases(quick=True) if c.withheld == (kind,))
    config, model_robot, params = drive_case_config(case)
    config = config.with_logger(rate_hz=1000.0, stamp_jitter_ms=0.0, dropout_prob=0.0)
    n = config.robot.n
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.2, 7)
    q = 0.3 * rng.uniform(-1, 1, (7, n)) + 0.02 * np.sin(40 * t)[:, None]
    rec = simulate_twin(config, PiecewisePolynomial.CubicShapePreserving(t, q.T, True), progress=False)
    tr = rec.truth
    s = MotionSignals(tr["t_true"], tr["q_true"], tr["qd"], tr["qdd"])
    link = (EFFECTS["viscous_coulomb"](n, **params["viscous_coulomb"]),)
    arm, model = SimModel(config.robot, link).predict(s), SimModel(model_robot, link).predict(s)
    pre = [e.torque(s) for e in config.effects if isinstance(e, PreSliding)]
    np.testing.assert_allclose(rec.tau - tr["tau_torque_noise"], arm + sum(pre), rtol=0, atol=1e-6)
    withheld = np.sqrt(np.mean((arm + sum(pre) - model) ** 2, axis=0))
    if kind == "presliding":
        assert np.abs(pre[0]).max() > 0.2
    else:                                  # the shared motor's friction, on both joints it turns with
        assert np.all(withheld[SHARED_MOTOR - 1:] > 0.05) and np.all(withheld[:SHARED_MOTOR - 1] < 1e-9)
    assert rec.meta["robot_description"]["drive"]["tau_kind"] == "drive"


def test_family_score_takes_the_shared_motors_friction_by_its_candidates_name():
    """A coupled-motor-friction case is right when the diagnosis names ``motor_friction`` (its candidate), in the
    family's own line as in the overall top-1; a null case that names something is a false positive."""
    from proprio.gap_benchmark.run import CaseResult, summarise

    cases = {c.name: c for c in drive_cases(quick=True)}
    res = [CaseResult(cases["drive:coupled_motor_friction@1/100Hz"], ["motor_friction"], ["motor_friction"], 0.5, 0.5,
                      1.0),
           CaseResult(cases["drive:rotor_inertia@1/100Hz"], ["stribeck"], ["stribeck"], 0.5, 0.5, 1.0),
           CaseResult(cases["drive:null#0/100Hz"], [], [], 0.0, 0.0, 1.0),
           CaseResult(cases["drive:null#0/1000Hz"], ["drive_offset"], ["drive_offset"], 0.1, 0.0, 1.0)]
    scores, text = summarise(res)
    assert scores["drive_top1"] == pytest.approx(0.5) and scores["drive_null_false_positive_rate"] == pytest.approx(0.5)
    assert "top-1 50.0 %" in text
