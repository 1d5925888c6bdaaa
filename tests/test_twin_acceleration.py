"""The twin's recorded q̈ is not registered at every step but recovered at block rate as (q̇ₖ₊₁ − q̇ₖ)/Δt
(proprio/diagrams/twin_chain.py): that is exact only because Drake's discrete plant reports its acceleration as the
same expression. These tests hold it to that, bit for bit, on the plain, the series-elastic and the coupled-drive
twins, and check the Recording's q̈ against the plant's own acceleration port."""
from __future__ import annotations

import numpy as np
import pytest
from pydrake.trajectories import PiecewisePolynomial

from proprio.diagrams.twin import build_twin_diagram, load_twin_config, simulate_twin, start_simulator
from proprio.effects import Elasticity


def path(desc, seconds: float = 3.0, seed: int = 3) -> PiecewisePolynomial:
    """A smooth path from t = 0 around the middle of the joint ranges (knots every 0.5 s, ±0.3 rad)."""
    knots = (desc.lower + desc.upper) / 2 + np.random.default_rng(seed).uniform(-0.3, 0.3,
                                                                                (int(2 * seconds) + 1, desc.n))
    return PiecewisePolynomial.CubicShapePreserving(np.arange(knots.shape[0]) * 0.5, knots.T, True)


def elastic_iiwa(tmp_path):
    """``iiwa14_twin`` with its commented series-elastic block switched on."""
    from proprio.configs import __file__ as configs
    from pathlib import Path
    text = (Path(configs).parent / "iiwa14_twin.yaml").read_text()
    for key in ("elasticity:", "  stiffness:", "  damping:"):
        text = text.replace(f"  # {key}" if key == "elasticity:" else f"  #   {key.strip()}",
                            f"  {key}" if key == "elasticity:" else f"    {key.strip()}")
    (tmp_path / "elastic_twin.yaml").write_text(text)
    config = load_twin_config(tmp_path / "elastic_twin.yaml")
    assert any(isinstance(e, Elasticity) for e in config.effects)
    return config


def plant_accelerations(config, traj, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The plant's acceleration port and velocities ``[steps + 1, n]`` at each step of the dynamics-only twin."""
    twin = build_twin_diagram(config, traj, measurement_chain=False)
    sim = start_simulator(twin, traj)
    instance = twin.plant.GetModelInstanceByName(config.robot.name)
    port = twin.plant.get_generalized_acceleration_output_port(instance)
    qdd, v = [], []
    for k in range(steps + 1):
        if k:                         # AdvanceTo(0) would already apply the update at t = 0
            sim.AdvanceTo(k * config.time_step)
        ctx = twin.plant.GetMyContextFromRoot(sim.get_context())
        qdd.append(port.Eval(ctx).copy())
        v.append(twin.plant.GetVelocities(ctx).copy())
    return np.array(qdd), np.array(v)


@pytest.mark.parametrize("name", ["iiwa14_twin", "elastic", "staubli_tx40_twin"])
def test_discrete_plant_acceleration_is_the_velocity_difference_exactly(name, tmp_path):
    config = elastic_iiwa(tmp_path) if name == "elastic" else load_twin_config(name)
    qdd, v = plant_accelerations(config, path(config.robot), 300)
    assert np.abs(qdd).max() > 1e-3                        # a motion, not rest
    np.testing.assert_array_equal(qdd[:-1], (v[1:] - v[:-1]) / config.time_step)


def test_recorded_qdd_is_the_plant_acceleration_port():
    config = load_twin_config("iiwa14_twin")
    traj = path(config.robot, seconds=2.5)
    rec = simulate_twin(config, traj, progress=False)
    steps = np.rint(rec.truth["t_true"] / config.time_step).astype(int)
    qdd, _ = plant_accelerations(config, traj, int(steps.max()))
    assert steps.size > 2000 and steps.max() > 2000          # samples on either side of block edges (1 000 steps)
    np.testing.assert_array_equal(rec.truth["qdd"], qdd[steps])
