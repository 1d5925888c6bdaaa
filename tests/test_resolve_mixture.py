"""Issue #25, the demo's mixture: Coulomb friction and a torque-sensor hysteresis that are BOTH in the data. The
selection names both, but their parameters trade off (the hysteresis takes the Coulomb level): a confounded pair
(:func:`proprio.diagnosis.discriminate.confounded_pairs`). The experiment of the pair is designed on the members each
refitted alone (:func:`~proprio.diagnosis.discriminate.pair_set`) and scored on their mixture; the joint fit on the old
data plus the experiment divides the shared torque between them.

The default-suite test runs the mechanism on a reduced case (rigid body + Coulomb + 6° hysteresis, one 20 s
recording at 50 Hz, the pair's two candidates); the demo's twin mixture through ``proprio diagnose --resolve`` is the
slow test (README, "Confusable effects")."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from proprio.description import load_robot
from proprio.diagnosis.ambiguity import Alternative, AmbiguitySet
from proprio.diagnosis.benchmark_cases import rfma_like_motion
from proprio.diagnosis.candidates import candidate_set
from proprio.diagnosis.data import SimModel
from proprio.diagnosis.discriminate import CONFOUND_CORRELATION, confounded_pairs, design_experiment, pair_set
from proprio.diagnosis.fitting import fit_candidates
from proprio.diagnosis.resolve import design_experiments, training_data
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS
from proprio.recording import Recording
from proprio.signals import MotionSignals
from proprio.systems.trajectories import sample_trajectory

RATE, NOISE = 50.0, 0.3                                     # Hz, N·m (the twin's torque noise on joints 1–4)
COULOMB = np.array([0.32, 0.18, 0.1, 0.18, 0.08, 0.13, 0.09])    # N·m, the twin's Coulomb levels (rounded)
SATURATION = np.array([0.45, 0.5, 0.25, 0.35, 0.12, 0.12, 0.1])  # N·m, the twin's hysteresis levels


def _alt(name, share, corr, tied=False):
    return Alternative(name, 0.3, share, corr, 1.0 if tied else 3.0, tied)


def _set(effect, alts, context, **kw):
    return AmbiguitySet(effect, 0.3, alts, [effect] + [a.name for a in alts if a.tied], 0.3, 1.0, {effect: 1.0},
                        context, **kw)


def test_confounded_pairs_are_two_named_effects_with_correlated_torques_not_tied():
    named_alt = _alt("viscous_coulomb", 0.9, 0.86)
    sets = [_set("hysteresis", [named_alt, _alt("sensor_gain", 0.9, 0.95)], ["viscous_coulomb"]),
            _set("viscous_coulomb", [_alt("hysteresis", 0.8, 0.86)], ["hysteresis"]),
            _set("ripple", [_alt("lost_motion", 3.4, -0.01, tied=True)], ["hysteresis"]),
            _set("lost_motion", [_alt("ripple", 0.9, CONFOUND_CORRELATION - 0.1)], ["ripple"])]
    pairs = confounded_pairs(sets)
    # sensor_gain is not named (a tie question, not a confounded pair); the pair is listed once; a tied set and an
    # uncorrelated alternative are not confounded pairs
    assert [(a.effect, other) for a, other in pairs] == [("hysteresis", "viscous_coulomb")]
    weak = [_set("hysteresis", [_alt("viscous_coulomb", 0.4, 0.9)], ["viscous_coulomb"]),
            _set("viscous_coulomb", [], ["hysteresis"])]
    assert confounded_pairs(weak) == []                      # explains too little of the effect's gain in its place
    # a tie of two named effects whose held-out torques do not correlate gets no experiment (both explain their part)
    unrelated = SimpleNamespace(ambiguity=[sets[2], _set("lost_motion", [], ["ripple"])])
    assert design_experiments(SimModel(load_robot("iiwa14_nominal")), unrelated) == []


@pytest.fixture(scope="module")
def mixture():
    robot = load_robot("iiwa14_nominal")
    n = robot.n
    effects = [EFFECTS["viscous_coulomb"](n, viscous=np.full(n, 0.1), coulomb=COULOMB),
               EFFECTS["hysteresis"](n, saturation=SATURATION, saturation_travel=np.full(n, math.radians(6.0)))]

    def record(t, q, qd, qdd, seed):
        s = MotionSignals(t, q, qd, qdd)
        tau = inverse_dynamics(robot, q, qd, qdd)
        for e in effects:
            tau = tau + e.torque(s.with_tau(tau))
        rng = np.random.default_rng(seed)
        return Recording(t=t, q=q + rng.normal(0.0, math.radians(5e-4), q.shape),
                         tau=tau + rng.normal(0.0, NOISE, tau.shape), meta={"robot": robot.name})

    model = SimModel(robot)
    old = record(*rfma_like_motion(robot, 1, 20.0, RATE)[:4], 1)
    return robot, model, record, old


def _levels(fit, n):
    return fit.thetas["viscous_coulomb"][n:], fit.thetas["hysteresis"][:n]


def test_the_pair_experiment_lets_the_joint_fit_divide_the_level(mixture):
    robot, model, record, old = mixture
    n = robot.n
    train = training_data(model, [old])
    cands = {c.name: c for c in candidate_set(model, train, ["viscous_coulomb", "hysteresis"])}
    w = 1.0 / np.maximum((train.residual ** 2).mean(axis=0), 1e-12)
    both = [cands["viscous_coulomb"], cands["hysteresis"]]
    before = fit_candidates(both, train, w, {}, sweeps=3)        # what the selection's last step fits on the old data
    hyst = _set("hysteresis", [_alt("viscous_coulomb", 0.9, 0.9)], ["viscous_coulomb"], fits={"hysteresis": before},
                candidates=cands, weights=w, sigma=np.full(n, NOISE), home=np.median(old.q, axis=0))
    (aset, other), = confounded_pairs([hyst, _set("viscous_coulomb", [], ["hysteresis"])])
    pair = pair_set(aset, other, train)
    assert pair.members == ["hysteresis", "viscous_coulomb"] and pair.context == [] and pair.tied
    assert set(pair.fits["hysteresis"].thetas) == {"hysteresis"}          # each alone in the pair's place
    assert set(pair.fits["viscous_coulomb"].thetas) == {"viscous_coulomb"}
    exp = design_experiment(model, pair, families=("triangles",), refit_top=2, mixed=True)
    assert exp is not None and exp.family == "triangles" and exp.duration <= 60.0 + 1e-6
    assert exp.pair and exp.worth_running and "both named" in exp.text()      # run even if one alone could mimic it
    assert np.isfinite(exp.score) and exp.score <= exp.raw_score + 1e-9    # refitting only removes separation
    new = record(*sample_trajectory(exp.trajectory, RATE), 2)
    after = fit_candidates(both, training_data(model, [old, new]), w, {}, sweeps=3)
    err = {k: [np.abs(lv / truth - 1.0) for lv, truth in zip(_levels(f, n), (COULOMB, SATURATION))]
           for k, f in (("before", before), ("after", after))}
    c_after, h_after = err["after"]
    assert c_after[0] <= 0.25 and h_after[0] <= 0.25, err["after"]       # joint 1: both levels within 25 %
    assert max(c_after[0], h_after[0]) < max(err["before"][0][0], err["before"][1][0]), err
