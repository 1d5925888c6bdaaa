"""The payload experiment of thesis §5 ("Cartesian force estimation", Table 5.4) on the twin.

An RFMA validation trajectory is run on the calibrated twin with 0, 500 and 1000 g at the flange; the external
force is estimated with a model that does not know the payload (the model of the bare robot), by both observers
(:mod:`proprio.diagrams.estimation`), and the force error f̂ − f_true is summarised per axis as RMSE and standard
deviation, per mass and per observer — the layout of Table 5.4. The true force is the twin's ``f_ext``: the
payload's weight *and* its inertial force during the motion.

:func:`error_budget` splits the Jacobian observer's force error into its sources using the twin's truth channels:

    τ_dyn − F(τ_meas) − Jᵀ f_true =   [τ_rbd,model(q̂, q̂̇, q̂̈) − F(τ_rbd,model(q, q̇, q̈))]     derivatives
                                    + F(τ_rbd,model − τ_rbd,real)(q, q̇, q̈)                  inertial parameters
                                    + [τ_int,model(q̂̇) − F(τ_link friction)]                friction + offsets
                                    − Σ_e F(τ_e)                                             each sensor effect e
                                    + remainder (simulation vs. RNEA, filtered truth)

with F the zero-phase filter applied to the measurements and (q, q̇, q̈) the true motion; each term is mapped through
the same J⁻ᵀ, so the signed terms add up to the observer's force error. Terms can cancel: an identified model
absorbs part of the sensor effects into its inertials and offsets, so its "inertial parameters" and "friction +
offsets" terms are large and anti-correlated with the sensor terms; their RMS values do not add.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.trajectories import PiecewisePolynomial
from proprio.progress import progress_bar

from proprio.description import load_robot
from proprio.dynamics import inverse_dynamics
from proprio.effects import EFFECTS
from proprio.io import atomic_write_text
from proprio.plots.experiments import plot_payload_errors
from proprio.kinematics import point_jacobian
from proprio.payload import Payload
from proprio.recording import Recording, save_recording
from proprio.conditioning import ConditioningConfig, zero_phase_lowpass
from proprio.diagrams.twin import TwinConfig, load_twin_config, simulate_twin
from proprio.diagrams.estimation import (DEFAULT_GAIN, OBSERVERS, EstimationResult, TorqueModel,
                                         conditioned_signals, estimate_wrench, load_torque_model)
from proprio.systems.observers import WrenchMapping, wrench_from_joint_torque
from proprio.systems.rfma import generate_rfma, load_rfma_config

__all__ = ["THESIS_RBD", "PayloadExperiment", "validation_trajectory", "error_budget", "format_table",
           "payload_experiment", "demo_payload_experiment"]

THESIS_RBD = {0.0: ([1.53, 1.74, 1.93], [5.11, 5.85, 6.30]), 0.5: ([0.90, 0.83, 4.77], [1.11, 1.19, 5.03]),
              1.0: ([1.65, 1.24, 9.26], [1.80, 1.85, 9.91])}
"""Thesis Table 5.4, RBD model: mass [kg] → (RMSE [x y z], σ [x y z]) of the force error [N]."""


_MAX_RFMA_TRIES = 4          # validation_trajectory: scaffold counts tried before giving up


def validation_trajectory(seconds: float, seed: int = 7, scaffolds: int = 3,
                          waypoints: tuple[int, int] = (800, 1000), joint_margin_deg: float = 10.0
                          ) -> PiecewisePolynomial:
    """An RFMA trajectory (§4.3) cut to ``seconds`` [s], starting at the first scaffold (so that it does not begin
    in the stretched, singular home pose) and shifted to t = 0. Uses the shipped RFMA config with ``scaffolds``
    scaffolds — more when those do not last ``seconds`` (the thesis' validation run is ≈ 9.4 min: 42260 samples at
    75 Hz) — shorter exploration phases (``waypoints``) and scaffolds ``joint_margin_deg`` inside the joint limits
    (the elastic twin overshoots a 2° margin in fast reaches)."""
    if not (np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a finite duration > 0 s, got {seconds}")
    for _ in range(_MAX_RFMA_TRIES):
        cfg = load_rfma_config(scaffolds=scaffolds, seed=seed, waypoints=waypoints,
                               joint_margin=float(np.radians(joint_margin_deg)))
        _, timed = generate_rfma(cfg)
        traj = timed.trajectory
        breaks = np.asarray(traj.get_segment_times())
        t_start = float(timed.phase_times[1])
        lasts = breaks[-1] - t_start
        if lasts >= seconds:
            break
        scaffolds = int(np.ceil(1.2 * scaffolds * seconds / max(lasts, 1e-3))) + 1     # the motion grows ∝ scaffolds
    else:
        raise ValueError(f"validation_trajectory: RFMA gives only {lasts:.1f} s of motion after {_MAX_RFMA_TRIES} "
                         f"scaffold counts, {seconds:g} s asked")
    i0 = int(np.searchsorted(breaks, t_start - 1e-9))
    i1 = min(int(np.searchsorted(breaks, breaks[i0] + seconds - 1e-9)), len(breaks) - 1)
    sub = traj.slice(i0, max(i1 - i0, 1))
    sub.shiftRight(-sub.start_time())
    return sub


def error_budget(model: TorqueModel, rec: Recording, mapping: WrenchMapping = WrenchMapping(),
                 conditioning: ConditioningConfig = ConditioningConfig()) -> dict[str, np.ndarray]:
    """Sources of the Jacobian observer's force error on a twin Recording (module docstring): ``name → [N,3]`` [N].

    Needs the twin's truth channels ``q_true``, ``tau_J_true`` and ``tau_<effect>`` and its ``meta`` (robot,
    effects). Also returns ``"total"`` (the observer's force error) so that the terms can be checked to add up.
    """
    missing = [k for k in ("q_true", "tau_J_true") if k not in rec.truth]
    if missing or rec.f_ext is None:
        raise ValueError(f"error_budget needs a twin Recording with f_ext and truth {missing or ['q_true']}")
    rec, sig, _ = conditioned_signals(rec, conditioning)
    real = load_robot(rec.meta["robot"])
    desc = model.description
    h = sig["time_step"]
    cutoff = np.asarray(rec.meta["conditioned"]["cutoff_hz"])
    q_true = rec.truth["q_true"]
    qd = rec.truth["qd"] if "qd" in rec.truth else rec.qd          # the twin's exact motion (truth), for scoring
    qdd = rec.truth["qdd"] if "qdd" in rec.truth else rec.qdd

    def low(x: np.ndarray) -> np.ndarray:
        return zero_phase_lowpass(x, 1.0 / h, cutoff, conditioning.order, conditioning.edge_cycles)

    rbd_model_true = inverse_dynamics(desc, q_true, qd, qdd)
    terms = {
        "derivatives (filtered q̇, q̈)": inverse_dynamics(desc, sig["q"], sig["qd"], sig["qdd"]) - low(rbd_model_true),
        "inertial parameters": low(rbd_model_true - inverse_dynamics(real, q_true, qd, qdd)),
    }
    effects = rec.meta.get("effects", {})
    link = [k for k in effects if k in EFFECTS and EFFECTS[k].place == "link" and f"tau_{k}" in rec.truth]
    link_friction = sum((rec.truth[f"tau_{k}"] for k in link), np.zeros_like(rec.tau))
    terms["friction + offset model (τ_int)"] = model.tau_int(sig["q"], sig["qd"], sig["qdd"]) - low(link_friction)
    for k in effects:
        if k in EFFECTS and EFFECTS[k].place == "sensor" and f"tau_{k}" in rec.truth:
            terms[f"sensor: {k}"] = -low(rec.truth[f"tau_{k}"])
    jac = point_jacobian(desc, sig["q"], np.asarray(mapping.contact_point, dtype=float))
    f_true = rec.f_ext[:, :3]
    tau_dyn = inverse_dynamics(desc, sig["q"], sig["qd"], sig["qdd"]) + model.tau_int(sig["q"], sig["qd"], sig["qdd"])
    total = wrench_from_joint_torque(jac, tau_dyn - sig["tau"], mapping)[0][:, :3] - f_true
    out = {name: wrench_from_joint_torque(jac, tau, mapping)[0][:, :3] for name, tau in terms.items()}
    out["remainder (simulation vs RNEA, filtered truth)"] = total - sum(out.values())
    out["total"] = total
    return out


@dataclass
class PayloadExperiment:
    """Results of :func:`payload_experiment`: per mass [kg] the estimation result, the error budget, the table."""
    model: str
    masses: tuple[float, ...]
    results: dict[float, EstimationResult]
    budgets: dict[float, dict[str, np.ndarray]]
    table_text: str
    files: list[Path] = field(default_factory=list)

    def stats(self) -> dict[str, dict]:
        """``{observer: {mass: {"rmse": [3], "std": [3]}}}`` [N] (JSON-able)."""
        out: dict[str, dict] = {}
        for obs in _OBSERVER_ROWS:
            out[obs] = {}
            for m in self.masses:
                rmse, std = _stats(self.results[m], obs)
                out[obs][str(m)] = {"rmse": rmse.round(4).tolist(), "std": std.round(4).tolist()}
        return out


_OBSERVER_ROWS = ("jacobian", "momentum", "jacobian force-only", "momentum force-only")


def _force_only(res: EstimationResult, obs: str, mapping: WrenchMapping, desc) -> np.ndarray:
    """Force-only (3-D) estimate from an observer's τ̂_ext, with the same solver (no re-run of the diagram); NaN
    inside gaps of the log, like the result's other channels."""
    fo = dataclasses.replace(mapping, force_only=True)
    out = np.full(res.wrench[obs].shape, np.nan)
    ok = ~res.gap
    jac = point_jacobian(desc, res.q[ok], np.asarray(fo.contact_point, dtype=float))
    out[ok] = wrench_from_joint_torque(jac, res.tau_ext[obs][ok], fo)[0]
    return out


def _error(res: EstimationResult, row: str) -> np.ndarray:
    """Force error f̂ − f_true ``[N_valid, 3]`` of one table row (an observer, or its force-only variant)."""
    mask = res.valid()
    return res.wrench[row][mask, :3] - res.f_true[mask, :3]


def _stats(res: EstimationResult, row: str) -> tuple[np.ndarray, np.ndarray]:
    """RMSE and σ [3] of a row's force error (for an observer row the same numbers as ``res.force_stats``)."""
    err = _error(res, row)
    return np.sqrt(np.mean(err ** 2, axis=0)), np.std(err, axis=0)


def _vec(v) -> str:
    return "[" + " ".join(f"{x:5.2f}" for x in v) + "]"


def format_table(exp_results: dict[float, EstimationResult], masses: tuple[float, ...], model_name: str,
                 budgets: dict[float, dict[str, np.ndarray]] | None = None) -> str:
    """Table 5.4 layout: per observer and mass the RMSE, σ and mean (bias) [x y z] of the force error [N], the
    thesis' RBD RMSE beside it, the payload force seen after taring with the 0 g run (mean f̂(m) − mean f̂(0 g),
    against the true mean difference), and (optionally) the RMS force error per error source."""
    lines = [f"Payload experiment (thesis §5, Table 5.4): force error f̂ − f_true [N], model '{model_name}'",
             f"{'observer':<22}{'mass':>6}  {'RMSE [x y z]':<21}  {'σ [x y z]':<21}  {'mean [x y z]':<21}  "
             f"{'thesis RBD RMSE':<21}"]
    for row in _OBSERVER_ROWS:
        for m in masses:
            rmse, std = _stats(exp_results[m], row)
            thesis = _vec(THESIS_RBD[m][0]) if m in THESIS_RBD else ""
            lines.append(f"{row:<22}{int(round(m * 1000)):>5}g  {_vec(rmse):<21}  {_vec(std):<21}  "
                         f"{_vec(_error(exp_results[m], row).mean(axis=0)):<21}  {thesis}")
    if 0.0 in masses and len(masses) > 1:
        lines.append("")
        lines.append("Payload seen after taring with the 0 g run: mean f̂(m) − mean f̂(0 g) [x y z] N "
                     "(truth in brackets)")
        base = exp_results[0.0]
        for row in _OBSERVER_ROWS:
            for m in (x for x in masses if x != 0.0):
                res = exp_results[m]
                seen = res.wrench[row][res.valid(), :3].mean(axis=0) - base.wrench[row][base.valid(), :3].mean(axis=0)
                true = res.f_true[res.valid(), :3].mean(axis=0) - base.f_true[base.valid(), :3].mean(axis=0)
                lines.append(f"{row:<22}{int(round(m * 1000)):>5}g  {_vec(seen):<21}  ({_vec(true)})")
    if budgets:
        lines.append("")
        lines.append("Error budget of the Jacobian observer: RMS force error [x y z] N per source (module docstring)")
        names = [k for k in next(iter(budgets.values())) if k != "total"] + ["total"]
        lines.append(f"{'source':<48}" + "".join(f"{int(round(m * 1000)):>5}g {'':<16}" for m in masses))
        for name in names:
            cells = []
            for m in masses:
                mask = exp_results[m].valid()
                cells.append(_vec(np.sqrt(np.mean(budgets[m][name][mask] ** 2, axis=0))))
            lines.append(f"{name:<48}" + "  ".join(f"{c:<21}" for c in cells))
    return "\n".join(lines)


def payload_experiment(model: str | Path | TorqueModel, out_dir: str | Path, seconds: float = 30.0,
                       masses: tuple[float, ...] = (0.0, 0.5, 1.0), seed: int = 7, gain: float = DEFAULT_GAIN,
                       mapping: WrenchMapping = WrenchMapping(),
                       conditioning: ConditioningConfig = ConditioningConfig(),
                       twin_config: str | TwinConfig = "iiwa14_twin",
                       com_flange: tuple[float, float, float] = (0.0, 0.0, 0.0),
                       progress: bool = True, save_recordings: bool = False) -> PayloadExperiment:
    """Run the payload experiment and write ``table.txt``, ``stats.json``, ``payload_<g>g.png`` (f̂ vs truth) and
    ``payload_errors.png`` to ``out_dir``.

    Args:
        model: a :class:`TorqueModel` or a spec for :func:`load_torque_model` (shipped robot / identified .npz /
            hybrid .pt, whose network then runs online in the estimation diagram; the error budget is computed
            for rigid-body models only).
        seconds: duration of the RFMA validation trajectory [s]. masses: payloads [kg] (point masses at
            ``com_flange`` in the flange frame [m]). seed: seed of the RFMA trajectory (the same motion for every
            mass) and of the twin's sensor noise (``seed + k`` for the k-th mass). gain: momentum observer K_O [1/s].
        twin_config: the twin: a config name or YAML, or a :class:`TwinConfig` (default: the calibrated
            ``iiwa14_twin``); for a hybrid model it logs at a rate the model reads
            (:meth:`~proprio.diagrams.hybrid_torque_model.HybridTorqueModel.log_rate`).
    """
    if not masses or not all(np.isfinite(m) and m >= 0 for m in masses):
        raise ValueError(f"masses must be a non-empty list of payload masses >= 0 kg, got {list(masses)}")
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    torque_model = model if not isinstance(model, (str, Path)) else load_torque_model(model)
    name = Path(model).name if isinstance(model, (str, Path)) and Path(model).suffix in (".npz", ".pt") else \
        getattr(torque_model, "name", torque_model.description.name)
    twin = twin_config if isinstance(twin_config, TwinConfig) else load_twin_config(twin_config)
    if hasattr(torque_model, "log_rate"):    # a hybrid reads recordings at a rate its own whole decimation reaches
        twin = twin.with_logger(rate_hz=torque_model.log_rate(twin.logger.rate_hz))
    traj = validation_trajectory(seconds, seed=seed)
    out = Path(out_dir)
    results: dict[float, EstimationResult] = {}
    budgets: dict[float, dict[str, np.ndarray]] = {}
    files: list[Path] = []
    for k, m in enumerate(progress_bar(masses, desc="payload experiment", unit="mass", enabled=progress)):
        payload = Payload(float(m), tuple(com_flange)) if m > 0 else None
        run = dataclasses.replace(twin, seed=seed + k)           # an independent sensor-noise draw per run
        rec = simulate_twin(run.with_payload(payload), traj, progress=False)
        if save_recordings:
            files.append(save_recording(rec, out / f"twin_{int(round(m * 1000))}g.npz"))
        res = estimate_wrench(torque_model, rec, gain=gain, mapping=mapping, conditioning=conditioning)
        for obs in OBSERVERS:
            res.wrench[f"{obs} force-only"] = _force_only(res, obs, mapping, torque_model.description)
        results[m] = res
        if not hasattr(torque_model, "signals"):     # the budget's terms are those of a rigid-body model
            budgets[m] = error_budget(torque_model, rec, mapping, conditioning)
        files.append(res.plot(out / f"payload_{int(round(m * 1000))}g.png",
                              title=f"{int(round(m * 1000))} g at the flange: f̂ (model {name}) vs truth"))
    table = format_table(results, tuple(masses), name, budgets)
    exp = PayloadExperiment(name, tuple(masses), results, budgets, table)
    atomic_write_text(out / "table.txt", table + "\n")
    atomic_write_text(out / "stats.json", json.dumps({"model": name, "twin": twin.name, "seconds": seconds,
                                                      "gain": gain, "conditioning": dataclasses.asdict(conditioning),
                                                      "stats": exp.stats()}, indent=2))
    files += [out / "table.txt", out / "stats.json", _plot_errors(exp, out / "payload_errors.png")]
    exp.files = files
    return exp


def _plot_errors(exp: PayloadExperiment, path: Path) -> Path:
    """Bar chart: RMSE per axis, per mass and observer, next to the thesis' RBD row."""
    rmse = {row: np.array([_stats(exp.results[m], row)[0] for m in exp.masses]) for row in _OBSERVER_ROWS}
    rmse["thesis RBD"] = np.array([THESIS_RBD.get(m, ([np.nan] * 3,))[0] for m in exp.masses], dtype=float)
    return plot_payload_errors(path, exp.masses, rmse, "thesis RBD",
                               f"payload experiment, model {exp.model} (ours) vs thesis Table 5.4 RBD")


def demo_payload_experiment(model: str | Path | TorqueModel, out_dir: str | Path,
                            seconds: float = 5.0) -> PayloadExperiment:
    """The payload experiment for ``proprio demo`` on a short trajectory (≈``seconds`` s per mass), without progress
    bars; its table is also written to ``out_dir/table.txt``."""
    return payload_experiment(model, out_dir, seconds=seconds, progress=False)
