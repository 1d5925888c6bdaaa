"""The torque sensor's terms of an identified backbone (``proprio identify --sensor-terms``): the twin's own laws, the
identification recovering their amplitudes, the model file, and one law in batch, per step, online and in the
estimation Diagram."""
import dataclasses

import numpy as np
import pytest

from proprio.causal_conditioning import causal_conditioning
from proprio.description import load_robot
from proprio.diagrams.estimation import build_estimation_diagram, estimate_rows, run_estimation_diagram
from proprio.diagrams.torque_model import RigidBodyTorqueModel, load_rigid_torque_model
from proprio.dynamics import inverse_dynamics
from proprio.effects import Hysteresis, LostMotion
from proprio.effects.sensor import Ripple, SensorOffsetGain
from proprio.identification.estimators import ols, sdp
from proprio.identification.model_io import ModelFileError, load_model, save_model
from proprio.identification.sensor_terms import (SENSOR_BOUNDS, SensorCarry, SensorTerms, SensorTermSettings,
                                                  sensor_columns)
from proprio.online import OnlineEstimator
from proprio.signals import MotionSignals

RATE = 200.0
HOME = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
GEAR = np.array([160.0, 160, 160, 160, 100, 160, 160])
# the twin's sensor (proprio/configs/iiwa14_twin.yaml, lost motion 10x larger so that a short run resolves it)
SAT = np.array([0.45, 0.5, 0.25, 0.35, 0.12, 0.12, 0.06])
SAT_LOAD = np.array([0.0, 0.02, 0.0, 0.02, 0.0, 0.0, 0.0])
LOST = np.array([0.32, 0.18, 0.073, 0.18, 0.035, 0.13, 0.087])
RIPPLE_SIN = np.array([0.08, 0.1, 0.05, 0.06, 0.03, 0.03, 0.02])
RIPPLE_COS = np.array([0.0, 0.04, -0.03, 0.02, 0.01, -0.02, 0.0])
GAIN = np.array([0.01, -0.008, 0.005, 0.01, 0.0, -0.005, 0.004])
OFFSET = np.array([0.4, -0.9, 0.2, 0.6, -0.1, 0.3, -0.15])


@pytest.fixture(scope="module")
def desc():
    return load_robot("iiwa14_identified")


def _motion(desc, seconds, rate=RATE, seed=0):
    """Multi-sine motion about HOME with reversals on every joint (amplitudes 0.15-0.5 rad)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    w = rng.uniform(0.4, 1.6, (3, desc.n))
    a = rng.uniform(0.05, 0.2, (3, desc.n))
    ph = rng.uniform(0, 2 * np.pi, (3, desc.n))
    arg = t[:, None, None] * w + ph
    q = HOME + np.sum(a * np.sin(arg), axis=1)
    qd = np.sum(a * w * np.cos(arg), axis=1)
    qdd = -np.sum(a * w ** 2 * np.sin(arg), axis=1)
    return t, q, qd, qdd


def _twin_sensor(desc, t, q, qd, qdd):
    """τ measured by the twin's sensor laws on the exact motion: the link torque (rigid body + friction) through the
    gauge's hysteresis, lost motion and ripple, then gain and offset (as TorqueSensor applies them)."""
    link = inverse_dynamics(desc, q, qd, qdd) + RigidBodyTorqueModel(desc).tau_int(q, qd, qdd)
    s = MotionSignals(t, q, qd, qdd, link)
    gauge = (Hysteresis(desc.n, saturation=SAT, load_gain=SAT_LOAD).torque(s)
             + LostMotion(desc.n, amplitude=LOST).torque(s)
             + Ripple(desc.n, sin_amplitude=RIPPLE_SIN, cos_amplitude=RIPPLE_COS, gear_ratio=GEAR).torque(s))
    sensed = link + gauge
    return sensed + SensorOffsetGain(desc.n, gain=GAIN, offset=OFFSET).torque(MotionSignals(t, q, qd, qdd, sensed))


def test_the_columns_are_the_twin_laws(desc):
    """Each column at its amplitude is the twin's effect function (Hysteresis with a load gain, LostMotion with a
    load gain, Ripple), to 1e-10."""
    t, q, qd, qdd = _motion(desc, 20.0)
    load = 30.0 * np.sin(q)             # any a-priori torque: the laws take its magnitude as the load
    settings = SensorTermSettings.defaults(desc.n, GEAR)
    cols, _ = sensor_columns(settings, q, qd, load)
    s = MotionSignals(t, q, qd, qdd, load)
    law = {"hysteresis": Hysteresis(desc.n, saturation=SAT, load_gain=SAT_LOAD).torque(s),
           "lost_motion": LostMotion(desc.n, amplitude=LOST, load_gain=0.001).torque(s),
           "ripple": Ripple(desc.n, sin_amplitude=RIPPLE_SIN, cos_amplitude=RIPPLE_COS, gear_ratio=GEAR).torque(s)}
    k = {name: settings.terms.index(name) for name in settings.terms}
    ours = {"hysteresis": SAT * cols[k["hysteresis"]] + SAT_LOAD * cols[k["hysteresis_load"]],
            "lost_motion": LOST * cols[k["lost_motion"]] + 0.001 * cols[k["lost_motion_load"]],
            "ripple": RIPPLE_SIN * cols[k["ripple_sin"]] + RIPPLE_COS * cols[k["ripple_cos"]]}
    for name in law:
        assert np.abs(law[name]).max() > 0.01, name          # the motion excites the law
        np.testing.assert_allclose(ours[name], law[name], rtol=0, atol=1e-10, err_msg=name)
    np.testing.assert_array_equal(cols[k["gain"]], load)


def test_pieces_with_the_carry_are_the_whole_motion(desc):
    """The columns over a motion cut into pieces, each continuing the previous one's carry (through its vector, as
    a Drake state holds it), equal the columns over the whole motion to 1e-12; so does one sample at a time."""
    t, q, qd, qdd = _motion(desc, 10.0)
    prior = 20.0 * np.cos(q)
    settings = SensorTermSettings.defaults(desc.n, GEAR)
    whole, _ = sensor_columns(settings, q, qd, prior)
    for cuts in ([0, 1, 137, 600, 1433, q.shape[0]], list(range(0, 301)) + [q.shape[0]]):
        parts, carry = [], None
        for a, b in zip(cuts[:-1], cuts[1:]):
            cols, end = sensor_columns(settings, q[a:b], qd[a:b], prior[a:b], carry)
            parts.append(cols)
            carry = SensorCarry.from_vector(end.vector())
        np.testing.assert_allclose(np.concatenate(parts, axis=1), whole, rtol=0, atol=1e-12)


def test_identification_recovers_the_sensor_amplitudes(desc, tmp_path):
    """OLS with the sensor terms on 60 s of the twin's sensor laws (exact motion, 0.01 N·m noise) recovers the
    hysteresis level at the run's mean load within 3 % (+0.01 N·m; a level and its load gain separate only where
    the load varies), the lost motion within 10 % (+0.01 N·m), the ripple amplitudes within 0.005 N·m, the gain
    difference of the loaded joints 2 and 4 within 0.002 (a gain is identifiable only against a torque it scales)
    and the offsets within 0.05 N·m; without them the fit is at least 10x worse. The model file keeps them."""
    t, q, qd, qdd = _motion(desc, 60.0)
    tau = _twin_sensor(desc, t, q, qd, qdd) + np.random.default_rng(1).normal(0.0, 0.01, q.shape)
    settings = SensorTermSettings.defaults(desc.n, GEAR)
    model = ols(desc, q, qd, qdd, tau, offsets=True, sensor=settings)
    got = dict(zip(settings.terms, np.asarray(model.sensor_terms.coefficients)))
    load = np.abs(tau).mean(axis=0)
    np.testing.assert_allclose(got["hysteresis"] + got["hysteresis_load"] * load, SAT + SAT_LOAD * load, rtol=0.03,
                               atol=0.01)
    np.testing.assert_allclose(got["lost_motion"] + got["lost_motion_load"] * load, LOST, rtol=0.1, atol=0.01)
    np.testing.assert_allclose(got["ripple_sin"], RIPPLE_SIN, rtol=0, atol=0.005)
    np.testing.assert_allclose(got["ripple_cos"], RIPPLE_COS, rtol=0, atol=0.005)
    g = got["gain"]
    assert abs((g[1] - g[3]) - (GAIN[1] - GAIN[3])) < 0.002
    np.testing.assert_allclose(model.offsets, OFFSET, rtol=0, atol=0.05)
    mse = np.mean((tau - model.torque(q, qd, qdd)) ** 2)
    plain = ols(desc, q, qd, qdd, tau, offsets=True)
    assert np.mean((tau - plain.torque(q, qd, qdd)) ** 2) > 10 * mse
    back = load_model(save_model(model, tmp_path / "m.npz"))
    assert back.sensor == settings and back.extras == model.extras
    np.testing.assert_array_equal(back.torque(q, qd, qdd), model.torque(q, qd, qdd))


def test_a_model_file_whose_extras_contradict_its_settings_is_refused(desc, tmp_path):
    t, q, qd, qdd = _motion(desc, 20.0)
    tau = _twin_sensor(desc, t, q, qd, qdd)
    model = ols(desc, q, qd, qdd, tau, offsets=True, sensor=SensorTermSettings.defaults(desc.n))
    bad = dataclasses.replace(model, sensor=SensorTermSettings.defaults(desc.n, GEAR))
    with pytest.raises(ModelFileError, match="sensor_terms"):
        load_model(save_model(bad, tmp_path / "bad.npz"))


@pytest.fixture(scope="module")
def sensor_model(desc, tmp_path_factory):
    """A physically consistent identified model with sensor terms (SDP: Drake's plant takes its inertials) and its
    estimator model from the file."""
    t, q, qd, qdd = _motion(desc, 30.0)
    tau = _twin_sensor(desc, t, q, qd, qdd)
    ident = sdp(desc, q, qd, qdd, tau, offsets=True, sensor=SensorTermSettings.defaults(desc.n, GEAR))
    path = save_model(ident, tmp_path_factory.mktemp("sensor") / "backbone.npz")
    return ident, load_rigid_torque_model(path)


def test_the_estimator_model_is_the_identified_model(desc, sensor_model):
    """τ_rigid of the identified inertials + the estimator model's τ_int (with the sensor terms) = the identified
    model's torque over a contiguous sequence, to 1e-9 N·m."""
    ident, model = sensor_model
    t, q, qd, qdd = _motion(desc, 5.0, rate=500.0, seed=3)
    got = inverse_dynamics(model.description, q, qd, qdd) + model.tau_int(q, qd, qdd)
    np.testing.assert_allclose(got, ident.torque(q, qd, qdd), rtol=0, atol=1e-9)
    bare = dataclasses.replace(model, sensor=None, prior=None)
    assert np.abs(model.tau_int(q, qd, qdd) - bare.tau_int(q, qd, qdd)).max() > 0.1


def _diagram_equals_streaming(model, design, t, q, tau, rate):
    """The estimation Diagram's rows for raw ``q, τ`` through ``design``; asserts the streaming estimator gives the
    same on every sample to 1e-10."""
    diagram, estimator, logger = build_estimation_diagram(model, {"t": t, "q": q, "tau": tau,
                                                                  "time_step": 1.0 / rate}, conditioning=design)
    expected = run_estimation_diagram(diagram, estimator, logger, t[-1], 1.0 / rate)[:t.size]
    est = OnlineEstimator.from_model(model, conditioning=design)
    got = np.array([est.step(t[k], q[k], tau[k]).vector for k in range(t.size)])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)
    return expected


def test_online_diagram_and_batch_agree_with_sensor_terms(desc, sensor_model):
    """With sensor terms (state carried per step): the streaming estimator equals the Diagram to 1e-10 on every
    sample, the batch laws on the causally conditioned signals equal it to 1e-9; the per-step law stepped over a
    sequence equals the batch τ_int to 1e-9."""
    _, model = sensor_model
    rate = 1000.0
    t, q, qd, qdd = _motion(desc, 3.0, rate=rate, seed=5)
    tau = _twin_sensor(desc, t, q, qd, qdd)
    design = causal_conditioning(rate, 10.0, desc.n, "q")
    expected = _diagram_equals_streaming(model, design, t, q, tau, rate)
    batch = estimate_rows(model, design.condition(np.hstack([q, tau])))
    np.testing.assert_allclose(batch, expected, rtol=0, atol=1e-9)
    law = model.torque_step()
    mem, nxt, out = law.initial_memory(), np.empty(law.memory_size), np.empty(2 * desc.n)
    rigid = inverse_dynamics(model.description, q, qd, qdd)
    stepped = np.empty_like(q)
    for k in range(t.size):
        law.step_into(np.concatenate([rigid[k], q[k], qd[k], qdd[k]]), mem, out, nxt)
        stepped[k] = out[desc.n:]
        mem, nxt = nxt, mem
    np.testing.assert_allclose(stepped, model.tau_int(q, qd, qdd), rtol=0, atol=1e-9)


def test_sensor_terms_round_trip_their_settings():
    st = SensorTermSettings.defaults(3, [100, -120, 160])
    assert SensorTermSettings.from_dict(st.to_dict()) == st and st.gear_ratio == (100.0, 120.0, 160.0)
    for field in ("saturation_travel", "reversal_velocity", "gear_ratio"):
        with pytest.raises(ValueError, match=field):
            SensorTermSettings.from_dict({**st.to_dict(), field: st.to_dict()[field][:2]})
    terms = SensorTerms(st, tuple((0.0,) * 3 for _ in st.terms))
    q = np.zeros((4, 3))
    tau, _ = terms.torque(q, q, q)
    np.testing.assert_array_equal(tau, 0.0)


def test_the_shipped_table5_model_finds_its_backbone_beside_it(tmp_path, monkeypatch):
    """``table5_hybrid.pt`` names its grey-box backbone ``proprio/configs/table5_backbone.npz``; run from any other
    folder it is found beside the model file, with its sensor terms."""
    from importlib.resources import files

    from proprio.diagrams.estimation import load_torque_model

    monkeypatch.chdir(tmp_path)
    model = load_torque_model(str(files("proprio.configs") / "table5_hybrid.pt"))
    assert model.backbone.sensor is not None and "hysteresis_load" in model.backbone.sensor.settings.terms


def test_identify_refuses_sensor_terms_on_a_drive_torque_arm(tmp_path, capsys):
    """A drive-torque arm (the TX40: τ from the motor currents) has no torque sensor: one clear line, before any data
    are read."""
    from proprio.cli import main

    rc = main(["identify", "--robot", "staubli_tx40", "--train", str(tmp_path / "never_read.npz"), "--sensor-terms",
               "--out", str(tmp_path / "m.npz")])
    err = capsys.readouterr().err
    assert rc != 0 and "--sensor-terms" in err and "drive torque" in err and not (tmp_path / "m.npz").exists()


def test_identification_recovers_the_twins_sensor_on_a_short_twin_run():
    """90 s of the calibrated twin (``iiwa14_twin``, logged at 150 Hz: measured q and τ only, the one conditioning
    path at 5 Hz): ``identify --sensor-terms``' fit gives back the twin's hysteresis levels within 5 % (+0.01 N·m),
    the load gains of the gravity-loaded joints 2 and 4 within 0.002 (the others within 0.005 of zero), the lost
    motion of joints 1-4 within 30 % (+0.003 N·m; it is 10x smaller than the hysteresis) and the gain difference of
    joints 2 and 4 within 0.003."""
    from proprio.conditioning import ConditioningConfig
    from proprio.diagrams.twin import simulate_twin
    from proprio.diagrams.twin_config import load_twin_config
    from proprio.experiments.payload import validation_trajectory
    from proprio.identification.recordings import identify_recordings

    cfg = load_twin_config("iiwa14_twin")
    cfg = dataclasses.replace(cfg, logger=dataclasses.replace(cfg.logger, rate_hz=150.0))
    rec = simulate_twin(cfg, validation_trajectory(90.0, seed=3), progress=False)
    settings = SensorTermSettings.defaults(cfg.robot.n)
    model, _ = identify_recordings([rec], [], cfg.robot, "ols", 0.5, True, None, ConditioningConfig(cutoff_hz=5.0),
                                   sensor=settings)
    got = dict(zip(settings.terms, np.asarray(model.sensor_terms.coefficients)))
    twin = {e.name: e for e in cfg.effects}
    hyst, lost, gain = twin["hysteresis"], twin["lost_motion"], twin["sensor_offset_gain"].gain
    np.testing.assert_allclose(got["hysteresis"], hyst.saturation, rtol=0.05, atol=0.01)
    np.testing.assert_allclose(got["hysteresis_load"], hyst.load_gain, rtol=0, atol=0.005)
    np.testing.assert_allclose(got["hysteresis_load"][[1, 3]], hyst.load_gain[[1, 3]], rtol=0, atol=0.002)
    np.testing.assert_allclose(got["lost_motion"][:4], lost.amplitude[:4], rtol=0.3, atol=0.003)
    assert abs((got["gain"][1] - got["gain"][3]) - (gain[1] - gain[3])) < 0.003


def test_a_hybrid_on_a_backbone_with_sensor_terms_streams_as_the_diagram_runs(desc, sensor_model):
    """A hybrid whose backbone carries sensor terms: the streaming step (backbone memory beside the network's) equals
    the Diagram (backbone memory in its hold, the network its own stage) to 1e-10 on every sample."""
    import torch

    from proprio.diagrams.hybrid_torque_model import HybridTorqueModel
    from proprio.learning.datasets import DataConfig
    from proprio.learning.features import feature_matrix, rotational_displacement
    from proprio.learning.models import HybridModel, ModelConfig

    _, backbone = sensor_model
    rate = 1000.0
    t, q, qd, qdd = _motion(desc, 1.5, rate=rate, seed=7)
    tau = _twin_sensor(desc, t, q, qd, qdd)
    torch.manual_seed(0)
    net = HybridModel(ModelConfig(arch="lstm2_fcl", lstm_hidden=12, rate_hz=rate))
    net.set_normalisation(feature_matrix(tau, q, qd, qdd, rotational_displacement(q)), 0.1 * tau)
    model = HybridTorqueModel(backbone, net, DataConfig(), "lstm2_fcl")
    design = causal_conditioning(rate, 10.0, desc.n, "q")
    _diagram_equals_streaming(model, design, t, q, tau, rate)


def test_the_stateless_rbd_backbone_system_refuses_sensor_terms(desc, sensor_model):
    from proprio.systems.rbd_backbone import RbdBackbone

    from proprio.diagrams.torque_model import TorqueModelSystem

    ident, model = sensor_model
    with pytest.raises(ValueError, match=r"load_rigid_torque_model\(path\) and use TorqueModelSystem\(that model, "
                                         r"period_s="):
        RbdBackbone(ident)
    system = TorqueModelSystem(model, period_s=1.0 / RATE)          # the advice works (model: from the file)
    assert system.law.memory_size == 1 + 9 * desc.n


def _recording(desc, seconds, seed):
    from proprio.recording import Recording

    t, q, qd, qdd = _motion(desc, seconds, seed=seed)
    return Recording(t=t, q=q, tau=_twin_sensor(desc, t, q, qd, qdd))


def test_the_training_table_restarts_the_sensor_state_at_each_recording(desc):
    """Two training recordings: the fit starts each from the virgin sensor state, and so does the training table
    (the per-recording predictions concatenated), not one sequence over the stack (whose state would flow from the
    first recording into the second)."""
    from proprio.identification.estimators import torque_error_table
    from proprio.identification.recordings import (TRIM_S, identify_recordings, piece_torque, pieces,
                                                   stack_recordings)

    recs = [_recording(desc, 20.0, 0), _recording(desc, 15.0, 1)]
    model, text = identify_recordings(recs, [], desc, "ols", TRIM_S, True,
                                      sensor=SensorTermSettings.defaults(desc.n, GEAR))
    (q, qd, qdd, tau), cond = stack_recordings(recs, TRIM_S)
    counts = pieces(cond, TRIM_S)
    cut = counts[0]
    each = np.concatenate([model.torque(q[:cut], qd[:cut], qdd[:cut]), model.torque(q[cut:], qd[cut:], qdd[cut:])])
    np.testing.assert_array_equal(piece_torque(model, q, qd, qdd, counts), each)
    assert np.abs(model.torque(q, qd, qdd) - each)[cut:cut + 50].max() > 1e-3       # the stack would differ
    assert torque_error_table(tau, each, "training (Table 4.4 layout)")[0] in text


def test_sdp_keeps_the_sensor_terms_in_the_effects_bounds(desc):
    """A hysteresis loop the wrong way round (a negative level, which OLS fits) is held at the effects' bounds by
    the SDP: levels ≥ 0, load gains in [0, MAX_LOAD_GAIN]; the gains stay free."""
    t, q, qd, qdd = _motion(desc, 20.0)
    link = inverse_dynamics(desc, q, qd, qdd) + RigidBodyTorqueModel(desc).tau_int(q, qd, qdd)
    tau = link - Hysteresis(desc.n, saturation=SAT).torque(MotionSignals(t, q, qd, qdd, link)) + OFFSET
    settings = SensorTermSettings.defaults(desc.n)
    free = dict(zip(settings.terms, np.asarray(ols(desc, q, qd, qdd, tau, offsets=True,
                                                   sensor=settings).sensor_terms.coefficients)))
    assert free["hysteresis"].min() < -0.1                              # the bound binds
    got = dict(zip(settings.terms, np.asarray(sdp(desc, q, qd, qdd, tau, offsets=True,
                                                  sensor=settings).sensor_terms.coefficients)))
    for name, (lo, hi) in SENSOR_BOUNDS.items():
        assert np.all(got[name] >= lo - 1e-7) and np.all(got[name] <= hi + 1e-7), name


def test_the_estimators_refuse_sensor_terms_on_a_drive_torque_arm():
    """The library call refuses what the CLI refuses: the sensor terms' a-priori torque has no drive terms."""
    tx = load_robot("staubli_tx40")
    z = np.zeros((50, tx.n))
    for fit in (ols, sdp):
        with pytest.raises(ValueError, match="drive torque"):
            fit(tx, z, z, z, z, sensor=SensorTermSettings.defaults(tx.n))
