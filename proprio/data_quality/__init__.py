"""Data-quality findings: what is wrong with (or worth knowing about) a log before anything is fitted to it.

:func:`assess` looks at one :class:`~proprio.recording.Recording` and returns a :class:`DataQuality`: a list of
:class:`Finding` (severity ``info`` / ``warning`` / ``problem``, a short ``code``, a one-line message naming the
channel and joint(s), and the numbers behind it) plus the one-line summary of the signal conditioning
(:meth:`proprio.conditioning.ConditionedSignals.describe`). :func:`format_findings` gives fixed-width text (what
``proprio inspect`` and ``proprio identify`` print), :func:`findings_markdown` a table for the diagnosis report and
:meth:`DataQuality.to_dict` a JSON-ready form. Every check is vectorised over samples; loops run over joints only.

The checks and their thresholds (:class:`QualityThresholds`, units stated there):

``jitter`` (t)
    Time steps ``Δt``: min / median / max, RMS deviation from the median and the fraction of steps longer than
    ``jitter_factor`` (1.5) × median. *info* when the steps are not uniform; *warning* when more than
    ``jitter_warn_fraction`` (1 %) of the steps are that long or a step is shorter than half the median.
``gap`` (t)
    Steps longer than ``max(conditioning.max_gap_s, 1.5 × median)`` — the same rule by which
    :func:`proprio.time_base.uniform_time_base` flags samples invalid, so the finding says what conditioning
    drops: count, missing time and where. *warning*; *problem* when more than ``gap_problem_fraction`` (10 %) of
    the duration is missing.
``duplicates`` (t)
    A Recording's time is strictly increasing, so duplicated stamps are merged where they enter: the CSV importer
    (:func:`proprio.recording.recording_from_csv`) averages the samples of a duplicated stamp and records the count in
    ``meta["duplicate_stamps"]``; this check reports it. *warning*.
``clipping`` (τ, needs a robot)
    ``|τ|`` *at* the effort limit — within ``clip_margin`` (1 %) of it on either side — in runs of at least
    ``clip_min_run`` (3) samples. *problem*.
``over_limit`` (τ, needs a robot)
    ``|τ|`` beyond ``(1 + clip_margin)`` × the effort limit: not clipping (a clipped signal sits at its limit) but a
    torque the robot is not rated for — a wrong limit in the description, another robot's data or a sensor fault.
    *warning*. (Beyond :data:`proprio.recording.PLAUSIBLE_LIMIT_FACTOR` × the limit the loader refuses the file.)
``flat_top`` (τ)
    Runs of at least ``flat_min_run`` (10) bit-identical samples at a joint's largest or smallest value, entered by a
    step larger than twice τ's quantisation step (a smooth quantised peak creeps in by one step; a saturated
    sensor or converter arrives with the signal's full slope). *problem*.
``quantised`` (q, τ)
    The step ``δ`` of which every non-zero ``|Δx|`` is an integer multiple (to ``quant_tolerance`` = 1 % of δ, for
    at least 98 % of the differences): the smallest non-zero ``|Δx|`` or its half or third. Reported when
    ``median |Δx| ≤ 1000 δ`` (a finer step is immaterial), in rad and degrees for q and N·m for τ. *info*; *warning*
    when more than ``quant_warn_zero_fraction`` (20 %) of the samples repeat their predecessor (a staircase that
    differences turn into spikes).
``tau_filtered`` (τ)
    A torque sensor's log carries a white-noise floor. From the Welch spectrum of ``Δτ`` on the raw samples (first
    differences pre-whiten, so window leakage from the large slow content cannot fake a floor), divided by the
    difference's ``4 sin²(π f h)``: the floor ``σ_floor = √(mean P(f ≥ fs/4) · fs/2)`` [N·m] and the fall-off
    ``median P[0.15 fs, 0.25 fs) / median P[0.4 fs, 0.5 fs]``. A joint is *filtered upstream* when its floor is
    below ``filtered_floor_ratio`` (1e-5, i.e. 100 dB, beyond a 16-bit converter's quantisation noise) of its
    signal RMS or the spectrum still falls by more than ``filtered_falloff`` (10×) across the upper band. The
    message gives the frequency above which the power stays ≥ 60 dB below its peak. *warning*: the sensor's noise
    and the filter's phase are not what the model sees.
``qd_lag`` / ``qd_gain`` / ``qd_consistent`` (q̇, when the Recording has one)
    The recorded q̇ against ``dq/dt`` from the conditioning path (:func:`proprio.conditioning.condition` with
    ``velocity = "q"``), both on its uniform grid, gaps and ``edge_fraction`` (5 %, at least ``1/min(cutoff)``) at
    each end dropped (upstream filters start up there). Per joint, the lag is the peak of their normalised
    cross-correlation within ``±max_lag_s`` (50 ms; every lag sees the same samples), refined by a parabola through
    the peak (sub-sample); positive means the recorded q̇ lags. Its standard error comes from the residual of
    ``q̇_rec ≈ g · q̇_ref(t − lag)`` (``σ² = Σe² / (g² Σ q̈_ref² N_eff)``, ``N_eff`` from the residual's lag-1
    autocorrelation); the pooled lag is the inverse-variance mean over joints (a slow joint, whose broad correlation
    peak hardly fixes a lag, counts little). The gain ``g`` is the least-squares factor. *warning* when the pooled
    ``|lag| > lag_warn_s`` (1 ms) and more than twice its standard error, or when a moving joint's
    ``|g − 1| > gain_warn`` (5 %); else *info*.
``qdd_noise`` (q̈)
    The RMS of the raw second difference of q (``np.gradient`` twice over the stamps, what a naive derivative gives)
    against the RMS of the conditioned q̈, with the conditioning's cutoffs and its estimated error ``σ(q̈)``: *info*
    when the raw one is more than ``qdd_noise_ratio`` (3×) larger. ``qdd_recorded`` (*info*): a q̈ channel exists;
    no stage uses it (no robot measures q̈).
"""
from __future__ import annotations

import dataclasses

from proprio.conditioning import ConditionedSignals, ConditioningConfig, condition
from proprio.data_quality.checks import _names, quantisation_step, runs, signal_findings
from proprio.data_quality.derivatives import acceleration_findings, velocity_findings
from proprio.data_quality.findings import (_RANK, SEVERITIES, DataQuality, Finding, QualityThresholds,
                                           findings_markdown, format_findings)
from proprio.description import RobotDescription
from proprio.recording import Recording, RecordingError

__all__ = ["SEVERITIES", "Finding", "DataQuality", "QualityThresholds", "assess", "format_findings",
           "findings_markdown", "quantisation_step", "runs"]


def assess(rec: Recording, robot: RobotDescription | None = None,
           conditioning: ConditioningConfig = ConditioningConfig(),
           thresholds: QualityThresholds = QualityThresholds(),
           conditioned: ConditionedSignals | None = None) -> DataQuality:
    """All data-quality findings on ``rec`` (module docstring), most severe first. ``robot`` names the joints and
    gives the effort limits for ``clipping``; ``conditioning`` is the configuration whose line is reported (and
    whose q̈ is compared); ``thresholds`` the limits of each check; ``conditioned``: ``rec`` already conditioned by
    ``conditioning`` (a caller that has it, such as the diagnosis, need not condition it again)."""
    th = thresholds
    names = _names(rec, robot)
    found = signal_findings(rec, names, robot, conditioning, th)
    try:
        cs = conditioned if conditioned is not None else condition(rec, conditioning)
        line = cs.describe()
    except RecordingError as exc:
        cs, line = None, f"conditioning: not possible ({exc})"
        found.append(Finding("warning", "conditioning", f"q: {exc}", "q"))
    if cs is not None:
        found += acceleration_findings(rec, cs, names, th)
        if rec.qd is not None:
            ref = cs if cs.velocity_source == "q" else condition(rec, dataclasses.replace(conditioning, velocity="q"))
            found += velocity_findings(rec, ref, names, th)
    found.sort(key=lambda f: -_RANK[f.severity])                  # stable: checks keep their order within a level
    return DataQuality(found, line, str(rec.meta.get("source", "")))
