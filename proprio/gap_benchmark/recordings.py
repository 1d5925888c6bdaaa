"""What the withheld-effect benchmark's families share in their data: the :class:`CaseData` a case's data come as, the
background sensor noise every case's data and model carry, and a case's three recordings through the Drake twin
(:mod:`proprio.gap_benchmark.case_data` makes the library cases' data, :mod:`proprio.gap_benchmark.drive` and
:mod:`proprio.gap_benchmark.confusable` their families')."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from proprio.description import RobotDescription
from proprio.gap_benchmark.cases import BenchmarkCase
from proprio.recording import Recording

__all__ = ["CaseData", "NOISE_STD", "ENCODER", "twin_recordings"]

NOISE_STD = 0.05                 # background torque-sensor noise [N·m] (present in data AND model unless withheld)
ENCODER = {"std": np.radians(0.0005), "resolution": np.radians(0.0001)}   # background encoder noise + quantisation
#                                  [rad], the shipped twin's: every case logs measured q, never exact q, q̇, q̈; the
#                                  model states it too (a withheld encoder_noise replaces its std by a larger one)


@dataclass
class CaseData:
    """A case's data: the robot the model stands on, the model's effects and their parameters, the training and the
    held-out recordings."""
    robot: RobotDescription
    model_effects: tuple[str, ...]
    model_params: dict[str, dict[str, Any]]
    train: list[Recording]
    holdout: list[Recording]


def twin_recordings(case: BenchmarkCase, configs: list[Any], meta: dict[str, Any] | None = None) -> list[Recording]:
    """The case's 3 recordings through the twin (``configs``: one ``TwinConfig`` per recording): short RFMA
    trajectories (2 scaffolds, 600–800 waypoints per exploration, own seed per recording; a seed for which RFMA finds
    no collision-free reach is replaced by a derived one), logged by each config's logger (q, τ; f_ext dropped);
    ``meta`` is added to each Recording's."""
    from proprio.diagrams.twin import simulate_twin
    from proprio.systems.rfma import RfmaError, generate_rfma, load_rfma_config

    recs = []
    for k in range(3):
        seed = (case.seed + 7919 * k) % (1 << 31)
        for attempt in range(5):                # RFMA may find no collision-free reach: next seed
            try:
                _, timed = generate_rfma(load_rfma_config(scaffolds=2, seed=seed, waypoints=(600, 800)),
                                         configs[k].robot)
                break
            except RfmaError:
                if attempt == 4:
                    raise
                seed = (seed + 104729) % (1 << 31)
        rec = simulate_twin(replace(configs[k], seed=seed), timed.trajectory, progress=False)
        meta_k = {**rec.meta, "source": "gap-benchmark (twin)", **(meta or {})}
        recs.append(Recording(t=rec.t, q=rec.q, tau=rec.tau, truth=rec.truth, meta=meta_k))
    return recs
