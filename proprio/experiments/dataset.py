"""``proprio dataset``: the twin simulated over many RFMA seeds × payloads into one directory with a manifest.

One task per (trajectory seed, payload): generate the RFMA trajectory (``proprio.systems.rfma``, ``scaffolds``
scaffolds, the seed), optionally cut to ``seconds``, simulate the twin along it (its noise seed: ``twin_seed`` or,
by default, the trajectory seed; the payload at the flange) and keep the Recording. Tasks run through
:func:`proprio.tasks.run_tasks`, so on this machine or on a Ray cluster with identical results; each task returns
its Recording to the driver, which writes ``<out>/rfma_s<seed>_p<payload>kg.npz`` (atomic) and rewrites
``manifest.json`` (atomic): format, the twin's name, its full config and its digest, the RFMA settings, and per
recording its file, seeds, payload, duration, samples, the SHA-256 of its arrays (``data_sha256``: t, q, τ, the
optional and truth channels — independent of the zip container and of run-time meta like wall time) and of the file.
A rerun skips the recordings already written (``<out>/.tasks/``).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from proprio.diagrams.twin import TwinConfig, load_twin_config, simulate_twin
from proprio.io import atomic_write_text, locked_dir, remove_stale_temps
from proprio.payload import Payload
from proprio.recording import Recording, load_recording, save_recording
from proprio.systems.rfma import generate_rfma, load_rfma_config
from proprio.systems.trajectories import truncate_trajectory
from proprio.tasks import Task, TaskRun, run_tasks, sigterm_as_interrupt

__all__ = ["DatasetSpec", "dataset_tasks", "simulate_dataset_item", "build_dataset", "recording_digest",
           "MANIFEST_FORMAT"]

MANIFEST_FORMAT = "proprio-dataset/v1"


@dataclass(frozen=True)
class DatasetSpec:
    """What to simulate: ``twin`` (shipped name or YAML path), RFMA ``seeds`` × ``payloads_kg`` (0 = none, at the
    flange origin), ``scaffolds`` per trajectory, ``seconds`` (cut each trajectory; None = whole), ``log_rate_hz``
    (None = the twin's), ``twin_seed`` (None = each trajectory's seed)."""
    twin: str = "iiwa14_twin"
    seeds: tuple[int, ...] = (0,)
    payloads_kg: tuple[float, ...] = (0.0,)
    scaffolds: int = 150
    seconds: float | None = None
    log_rate_hz: float | None = None
    twin_seed: int | None = None


def recording_digest(rec: Recording) -> str:
    """SHA-256 over the Recording's arrays (name, dtype, shape, bytes; sorted by name), not its meta."""
    arrays: dict[str, np.ndarray] = {"t": rec.t, "q": rec.q, "tau": rec.tau}
    for name in ("qd", "qdd", "f_ext"):
        if getattr(rec, name, None) is not None:
            arrays[name] = getattr(rec, name)
    arrays.update({f"truth__{k}": v for k, v in rec.truth.items()})
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _file_name(seed: int, payload: float) -> str:
    return f"rfma_s{seed}_p{payload:g}kg.npz"


def simulate_dataset_item(twin_config: dict[str, Any], twin_source: str, seed: int, scaffolds: int,
                          payload_kg: float, seconds: float | None, log_rate_hz: float | None,
                          twin_seed: int) -> Recording:
    """One task: the RFMA trajectory of ``seed`` on the twin given by its config mapping (shipped to the worker by
    value), simulated with noise seed ``twin_seed`` and the payload; returns the Recording."""
    config = dataclasses.replace(TwinConfig.from_dict(twin_config, twin_source), seed=int(twin_seed))
    if log_rate_hz is not None:
        config = config.with_logger(rate_hz=float(log_rate_hz))
    _, timed = generate_rfma(load_rfma_config(scaffolds=int(scaffolds), seed=int(seed)), config.robot)
    traj = timed.trajectory
    if seconds is not None:
        traj = truncate_trajectory(traj, float(seconds))
    payload = Payload(float(payload_kg)) if payload_kg > 0 else None
    rec = simulate_twin(config, traj, payload=payload, progress=False)
    rec.meta.update({"rfma_seed": int(seed), "rfma_scaffolds": int(scaffolds)})
    return rec


def dataset_tasks(spec: DatasetSpec) -> tuple[list[Task], dict[str, Any]]:
    """The tasks of a dataset and the twin part of its manifest (name, config, digest)."""
    if not spec.seeds or not spec.payloads_kg:
        raise ValueError("dataset: give at least one seed and one payload")
    if spec.scaffolds < 1:
        raise ValueError(f"dataset: scaffolds must be >= 1, got {spec.scaffolds}")
    if spec.seconds is not None and not spec.seconds > 0:
        raise ValueError(f"dataset: seconds must be > 0, got {spec.seconds}")
    if not all(np.isfinite(p) and p >= 0 for p in spec.payloads_kg):
        raise ValueError(f"dataset: payloads must be finite masses >= 0 kg, got {list(spec.payloads_kg)}")
    config = load_twin_config(spec.twin)            # validates here, before any task starts
    if spec.log_rate_hz is not None:
        config.with_logger(rate_hz=float(spec.log_rate_hz))       # the logger's checks, before any task starts
    raw = json.loads(json.dumps({"name": config.name, **config.raw}, default=str))
    digest = hashlib.sha256(json.dumps(raw, sort_keys=True).encode()).hexdigest()
    tasks = []
    for seed in spec.seeds:
        for payload in spec.payloads_kg:
            twin_seed = seed if spec.twin_seed is None else spec.twin_seed
            item = {"trajectory_seed": int(seed), "twin_seed": int(twin_seed), "payload_kg": float(payload),
                    "scaffolds": int(spec.scaffolds), "seconds": spec.seconds, "log_rate_hz": spec.log_rate_hz}
            tasks.append(Task(_file_name(seed, payload), simulate_dataset_item,
                              {"twin_config": raw, "twin_source": config.name, "seed": int(seed),
                               "scaffolds": int(spec.scaffolds), "payload_kg": float(payload),
                               "seconds": spec.seconds, "log_rate_hz": spec.log_rate_hz, "twin_seed": int(twin_seed)},
                              {**item, "twin_config_sha256": digest}))
    return tasks, {"name": config.name, "config_sha256": digest, "config": raw}


def build_dataset(spec: DatasetSpec, out_dir: str | Path, backend: str = "local", address: str | None = None,
                  workers: int | None = None, progress: bool = True) -> tuple[dict[str, Any], TaskRun]:
    """Simulate every (seed, payload) of ``spec`` not yet in ``out_dir`` and write the Recordings and
    ``manifest.json`` (module docstring). Returns ``(manifest, TaskRun)``; failed items are listed in the manifest
    under ``failed`` with their config.

    One run per directory: the run holds ``out_dir``'s lock (:func:`proprio.io.locked_dir`) from the first file to
    the manifest, so a second run into it is refused (:class:`proprio.io.DirectoryLocked`) rather than writing a
    manifest whose digests describe the other run's files; under the lock it deletes the temporary files a killed
    run left behind. SIGTERM or Ctrl-C stop the workers and leave no temporary file (:mod:`proprio.tasks`)."""
    out = Path(out_dir)
    tasks, twin = dataset_tasks(spec)
    with sigterm_as_interrupt(), locked_dir(out):
        remove_stale_temps(out, [t.key for t in tasks] + ["manifest.json"])
        return _build_locked(tasks, twin, spec, out, backend, address, workers, progress)


def _build_locked(tasks: list[Task], twin: dict[str, Any], spec: DatasetSpec, out: Path, backend: str,
                  address: str | None, workers: int | None, progress: bool) -> tuple[dict[str, Any], TaskRun]:

    def store(task: Task, rec: Recording) -> dict[str, Any]:
        path = save_recording(rec, out / task.key)
        return {"file": task.key, **dict(task.config), "duration_s": float(rec.t[-1] - rec.t[0]),
                "samples": int(rec.t.shape[0]), "data_sha256": recording_digest(load_recording(path)),
                "file_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                "sim_wall_s": rec.meta.get("sim_wall_s")}

    run = run_tasks(tasks, out / ".tasks", store, backend=backend, address=address, workers=workers,
                    progress=progress, desc="dataset", kept=lambda task, rec: (out / task.key).exists())
    manifest = {"format": MANIFEST_FORMAT, "twin": twin,
                "rfma": {"scaffolds": spec.scaffolds, "seconds": spec.seconds, "config": "proprio/configs/rfma.yaml"},
                "recordings": [run.records[t.key] for t in tasks if t.key in run.records],
                "failed": [{"file": f.key, "config": f.config, "error": f.error} for f in run.failures]}
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=1, sort_keys=True))
    return manifest, run


def seeds_from(values: Sequence[str]) -> tuple[int, ...]:
    """Seeds from CLI words: integers or ranges ``A-B`` (inclusive), e.g. ``11 12 20-23``."""
    seeds: list[int] = []
    for v in values:
        try:
            if "-" in v.strip("-"):
                a, b = v.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                seeds.extend(range(lo, hi + 1))
            else:
                seeds.append(int(v))
        except ValueError:
            raise ValueError(f"--seeds: {v!r} is neither an integer nor a range A-B") from None
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds: repeated seed(s) in {values}")
    return tuple(seeds)
