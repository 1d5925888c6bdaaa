"""Load-dependent friction (issue 39): the law once (proprio.friction_law), the effect, the twin's drive, the
identification columns and the benchmark's cases."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from proprio import friction_law
from proprio.description import load_robot
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS, LoadFriction
from proprio.gap_benchmark.cases import make_cases
from proprio.gap_benchmark.drive import drive_cases
from proprio.identification.estimators import identify
from proprio.identification.model_io import load_model, save_model
from proprio.signals import MotionSignals


def _motion(n: int, samples: int = 3000, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 30.0, samples)
    w, a, ph = rng.uniform(0.2, 0.8, (3, n)), rng.uniform(0.3, 0.8, (3, n)), rng.uniform(0, 6, (3, n))
    arg = [w[k] * (k + 1) * t[:, None] + ph[k] for k in range(3)]
    q = sum(a[k] * np.sin(arg[k]) for k in range(3))
    qd = sum(a[k] * w[k] * (k + 1) * np.cos(arg[k]) for k in range(3))
    qdd = sum(-a[k] * (w[k] * (k + 1)) ** 2 * np.sin(arg[k]) for k in range(3))
    return t, q, qd, qdd


def test_law_is_dissipative_grows_with_load_and_inverts_exactly():
    rng = np.random.default_rng(1)
    qd, tau = rng.normal(0, 0.3, (500, 7)), rng.normal(0, 40, (500, 7))
    k, c0 = rng.uniform(0.01, 0.05, 7), rng.uniform(0.05, 0.2, 7)
    f = friction_law.load_coulomb(qd, c0, k, tau)
    assert np.all(f * qd >= 0)
    assert np.allclose(f, (c0 + k * np.abs(tau)) * np.tanh(qd / friction_law.SMOOTH_VELOCITY))
    # the twin's inversion: u − k|u|s = net has the root load_from_net(net, s, k)
    s = friction_law.smooth_sign(qd)
    u = friction_law.load_from_net(tau, s, k)
    assert np.allclose(u - k * np.abs(u) * s, tau, atol=1e-12)


def test_effect_regressor_matches_torque_and_needs_the_load():
    n = 7
    t, q, qd, qdd = _motion(n, 400)
    tau = np.random.default_rng(2).normal(0, 30, q.shape)
    eff = LoadFriction(n, coulomb=0.1, load_gain=0.02)
    s = MotionSignals(t, q, qd, qdd, tau)
    assert np.allclose(np.einsum("tnp,p->tn", eff.regressor(s), eff.vector()), eff.torque(s), atol=1e-12)
    assert EFFECTS["load_friction"] is LoadFriction
    with pytest.raises(ValueError, match="tau"):
        eff.torque(MotionSignals(t, q, qd, qdd))


def test_twin_applies_it_on_the_transmitted_torque():
    """The twin's drive applies the law per step on the transmitted torque; the log recovers that torque exactly
    (τ_J = τ_rbd + every link-side effect), and the friction grows with the load (joint 2 carries gravity)."""
    from proprio.diagrams.twin import simulate_twin
    from proprio.diagrams.twin_config import load_twin_config
    from proprio.systems.trajectories import truncate_trajectory
    from proprio.experiments.payload import validation_trajectory

    cfg = load_twin_config("iiwa14_twin")
    n = cfg.robot.n
    cfg = dataclasses.replace(cfg, effects=list(cfg.effects) + [LoadFriction(n, coulomb=0.05, load_gain=0.03)])
    rec = simulate_twin(cfg, truncate_trajectory(validation_trajectory(3.0, seed=3), 2.0), progress=False)
    tr = rec.truth
    link = sum(tr[f"tau_{e.name}"] for e in cfg.effects if e.place == "link")
    assert np.abs(tr["tau_J_true"] - tr["tau_rbd"] - link).max() < 1e-9
    level = np.abs(tr["tau_load_friction"]) / np.maximum(np.abs(np.tanh(tr["qd"] / 0.05)), 1e-3)
    moving = np.abs(tr["qd"]) > 0.2
    # the level is F_c0 + k|τ_load| with τ_load ≈ τ_J (the rotor's inertial torque aside)
    expect = 0.05 + 0.03 * np.abs(tr["tau_J_true"])
    assert np.median(np.abs(level[moving] - expect[moving]) / expect[moving]) < 0.05
    assert level[moving[:, 1], 1].mean() > 3 * 0.05


@pytest.mark.parametrize("method", ["ols", "sdp"])
def test_identification_fits_the_load_gains(method, tmp_path):
    desc = load_robot("iiwa14_identified")
    t, q, qd, qdd = _motion(desc.n)
    k_true = np.random.default_rng(3).uniform(0.01, 0.03, desc.n)
    rest = (inverse_dynamics(desc, q, qd, qdd) + np.asarray(desc.friction_viscous) * qd
            + friction_law.viscous_coulomb(qd, 0.0, np.asarray(desc.friction_coulomb)))
    tau = friction_law.load_from_net(rest, friction_law.smooth_sign(qd), k_true)
    model = identify(desc, q, qd, qdd, tau, method, load_friction=True)
    assert np.allclose(model.load_gain, k_true, atol=1e-6)
    assert np.abs(model.torque(q, qd, qdd) - tau).max() < 1e-6
    again = load_model(save_model(model, tmp_path / "m.npz"))
    assert again.extras == ("load_gain",) and np.abs(again.torque(q, qd, qdd) - tau).max() < 1e-6
    plain = identify(desc, q, qd, qdd, tau, "ols")
    assert np.abs(plain.torque(q, qd, qdd) - tau).max() > 0.1          # without the columns it cannot fit


def test_benchmark_families_withhold_it_at_two_magnitudes_and_move_no_other_case():
    for quick in (True, False):
        names = [c.name for c in make_cases(quick)]
        assert {"load_friction@0.5", "load_friction@1"} <= set(names)
        twin = [c.name for c in make_cases(quick, twin=True)]
        assert {"twin:load_friction@0.5", "twin:load_friction@1"} <= set(twin)
        drive = [c.name for c in drive_cases(quick)]
        assert {"drive:load_friction@0.5/100Hz", "drive:load_friction@1/1000Hz"} <= set(drive)
    # a kind added later is never drawn as a null case's modelled effect (the null cases stay what they were)
    assert not any("load_friction" in c.modelled for c in make_cases(False) + make_cases(False, twin=True))


def test_a_description_asks_for_it_and_identify_fits_it(tmp_path, capsys):
    """``friction: {load_dependent: true}`` in a robot YAML (alone or beside the coefficients) makes ``proprio
    identify`` fit the load gains without the flag; the flag and the description together are the same fit; a
    description that does not say so fits none; a value that is not a boolean is refused naming the field."""
    import json

    import yaml

    from proprio.cli import main
    from proprio.description import DescriptionError, robot_from_dict

    desc = load_robot("iiwa14_identified")
    d = desc.to_dict()
    assert "load_dependent" not in d["friction"] and not desc.friction_load_dependent
    alone = robot_from_dict({**d, "friction": {"load_dependent": True}})
    assert alone.friction_load_dependent and not alone.has_friction
    asked = robot_from_dict({**d, "friction": {**d["friction"], "load_dependent": True}})
    assert asked.friction_load_dependent and asked.friction_coulomb == desc.friction_coulomb
    assert robot_from_dict(asked.to_dict()) == asked                                 # written back as read
    assert not asked.without_friction().friction_load_dependent
    with pytest.raises(DescriptionError, match=r"friction\.load_dependent: expected true or false"):
        robot_from_dict({**d, "friction": {**d["friction"], "load_dependent": "yes"}})

    t, q, qd, qdd = _motion(desc.n)
    k_true = np.random.default_rng(3).uniform(0.01, 0.03, desc.n)
    rest = (inverse_dynamics(desc, q, qd, qdd) + np.asarray(desc.friction_viscous) * qd
            + friction_law.viscous_coulomb(qd, 0.0, np.asarray(desc.friction_coulomb)))
    tau = friction_law.load_from_net(rest, friction_law.smooth_sign(qd), k_true)
    rec = tmp_path / "rec.npz"
    with open(rec, "wb") as fh:
        np.savez(fh, t=t, q=q, tau=tau, meta=np.array(json.dumps({"robot": desc.name})))
    (tmp_path / "plain.yaml").write_text(yaml.safe_dump(d))
    (tmp_path / "asked.yaml").write_text(yaml.safe_dump(asked.to_dict()))
    gains = {}
    for name, robot, flag in (("plain", "plain.yaml", []), ("asked", "asked.yaml", []),
                              ("both", "asked.yaml", ["--load-friction"]), ("flag", "plain.yaml", ["--load-friction"])):
        out = tmp_path / f"{name}.npz"
        assert main(["identify", "--robot", str(tmp_path / robot), "--train", str(rec), "--out", str(out)]
                    + flag) == 0
        model = load_model(out)
        gains[name] = model.load_gain if "load_gain" in model.extras else None
        said = capsys.readouterr().out
        assert ("the description's friction.load_dependent" in said) == (robot == "asked.yaml")
    assert gains["plain"] is None
    assert np.abs(gains["asked"] - k_true).max() < 0.005
    assert np.array_equal(gains["asked"], gains["both"]) and np.array_equal(gains["asked"], gains["flag"])


def test_the_estimator_model_carries_the_load_gains(tmp_path):
    """An identified model with load gains, loaded for the estimator (``load_rigid_torque_model``): τ_rigid + its
    τ_int is the identified model's torque (1e-9 N·m; without the gains it is not), its per-step law stepped over
    the motion is its batch τ_int (1e-9), and the streaming estimator equals the estimation Diagram on every sample
    (1e-10) and the batch rows (τ_dyn − τ 1e-9; the observer and the wrenches 1e-8, as without the gains)."""
    from proprio.causal_conditioning import causal_conditioning
    from proprio.diagrams.estimation import build_estimation_diagram, estimate_rows, run_estimation_diagram
    from proprio.diagrams.torque_model import load_rigid_torque_model
    from proprio.online import OnlineEstimator

    desc = load_robot("iiwa14_identified")
    t, q, qd, qdd = _motion(desc.n, 3001)
    k_true = np.random.default_rng(3).uniform(0.01, 0.03, desc.n)
    rest = (inverse_dynamics(desc, q, qd, qdd) + np.asarray(desc.friction_viscous) * qd
            + friction_law.viscous_coulomb(qd, 0.0, np.asarray(desc.friction_coulomb)))
    tau = friction_law.load_from_net(rest, friction_law.smooth_sign(qd), k_true)
    ident = identify(desc, q, qd, qdd, tau, "sdp", load_friction=True)
    model = load_rigid_torque_model(save_model(ident, tmp_path / "m.npz"))
    np.testing.assert_array_equal(model.load_gain, ident.load_gain)
    rigid = inverse_dynamics(model.description, q, qd, qdd)
    np.testing.assert_allclose(rigid + model.tau_int(q, qd, qdd), ident.torque(q, qd, qdd), rtol=0, atol=1e-9)
    bare = dataclasses.replace(model, load_gain=None)
    assert np.abs(model.tau_int(q, qd, qdd) - bare.tau_int(q, qd, qdd)).max() > 0.1
    law = model.torque_step()
    out, mem = np.empty(2 * desc.n), law.initial_memory()
    stepped = np.empty_like(q)
    for k in range(t.size):
        law.step_into(np.concatenate([rigid[k], q[k], qd[k], qdd[k]]), mem, out, mem.copy())
        stepped[k] = out[desc.n:]
    np.testing.assert_allclose(stepped, model.tau_int(q, qd, qdd), rtol=0, atol=1e-9)
    rate, keep, home = 100.0, slice(0, 1000), np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])   # away from q = 0
    t, q, qd, qdd = t[keep], home + 0.3 * q[keep], 0.3 * qd[keep], 0.3 * qdd[keep]
    tau = ident.torque(q, qd, qdd)
    design = causal_conditioning(rate, 10.0, desc.n, "q")
    diagram, estimator, logger = build_estimation_diagram(model, {"t": t, "q": q, "tau": tau, "time_step": 1 / rate},
                                                          conditioning=design)
    expected = run_estimation_diagram(diagram, estimator, logger, t[-1], 1.0 / rate)[:t.size]
    est = OnlineEstimator.from_model(model, conditioning=design)
    got = np.array([est.step(t[k], q[k], tau[k]).vector for k in range(t.size)])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)
    batch = estimate_rows(model, design.condition(np.hstack([q, tau])))
    torques = slice(14, 14 + desc.n)                                                     # τ_dyn − τ
    np.testing.assert_allclose(batch[:, torques], expected[:, torques], rtol=0, atol=1e-9)
    # the observer's recursion over 10 s at 100 Hz and the wrenches: 1e-9 to 2e-9 apart without the gains too
    np.testing.assert_allclose(batch, expected, rtol=0, atol=1e-8)
