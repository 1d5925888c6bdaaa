"""The diagnosis' long-log paths give what the direct computations give: the order spectrum's Lomb–Scargle without
its [N, K] temporaries, and candidate torques evaluated at the kept samples only or with a cached reversal travel."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from proprio.diagnosis.candidates.base import EffectCandidate
from proprio.diagnosis.data import GapData
from proprio.diagnosis.localisation import _lombscargle
from proprio.signals import MotionSignals


@pytest.mark.parametrize("freqs", [np.arange(1.0, 400.25, 0.25), np.arange(0.5, 2.5, 0.005),
                                   np.array([1.0, 2.0, 3.5, 7.0])])
def test_lombscargle_equals_scipys(freqs):
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(-2.0, 2.5, 1000))
    y = np.sin(37.25 * x) + 0.3 * rng.standard_normal(x.size)
    y -= y.mean()
    ref = signal.lombscargle(x, y, freqs, normalize=False)
    assert np.max(np.abs(_lombscargle(x, y, freqs) - ref)) <= 1e-10 * np.max(ref)


def _data(n_rec: int = 2, n: int = 3, samples: int = 4000) -> GapData:
    rng = np.random.default_rng(5)
    sigs, idx = [], []
    for _ in range(n_rec):
        t = np.arange(samples) * 0.005
        phase = rng.uniform(0, 2 * np.pi, n)
        q = 0.4 * np.sin(1.3 * t[:, None] + phase) + 0.1 * np.sin(4.1 * t[:, None])
        qd = np.gradient(q, t, axis=0)
        sigs.append(MotionSignals(t, q, qd, np.gradient(qd, t, axis=0), 5.0 * np.cos(t[:, None] + phase)))
        idx.append(np.flatnonzero(rng.random(samples) < 0.05))
    zeros = [np.zeros_like(s.q) for s in sigs]
    return GapData([], sigs, zeros, zeros, zeros, idx, list(range(n_rec)))


@pytest.mark.parametrize("name", ["stribeck", "friction_warmup", "hysteresis", "lost_motion", "presliding"])
def test_candidate_torque_at_the_kept_samples_equals_the_full_evaluation(name):
    data = _data()
    cand = EffectCandidate(name, 3)
    theta = cand.starts(_data())[0] if cand.n_params else np.zeros(0)
    theta = np.asarray(theta, dtype=float) * 1.3 + 0.01
    lo, hi = cand.bounds()
    theta = np.clip(theta, lo, np.where(np.isfinite(hi), hi, theta))
    eff = cand.proto.with_vector(theta)
    direct = data.stack([eff.torque(s) for s in data.signals])
    for _ in range(2):                                  # the second call reads the cached travel / kept signals
        np.testing.assert_allclose(cand.torque(theta, data), direct, rtol=1e-12, atol=1e-12)
    views = [v for k, v in data.cache.items() if k[0] in ("travel", "kept_signals")]
    cut = [x.q.shape[0] for v in views for x in (v if isinstance(v, list) else [v[0]])]
    assert cut and max(cut) < 0.5 * data.signals[0].q.shape[0]       # evaluated on a cut of each recording
