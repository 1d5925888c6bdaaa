"""The execution engine (proprio.tasks) and the three commands on it: local vs Ray give the same results, a rerun
runs only what is missing, a failing task is reported with its config while the others are kept (issue #15).

One local Ray instance (2 CPUs, no dashboard) serves the whole module."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from proprio.cli import main
from proprio.tasks import Shared, Task, run_tasks

ray = pytest.importorskip("ray", reason="the Ray path needs ray (pip install 'proprio[ray]')")

GRID_YAML = """
grid: {archs: [mlp7, lstm2_fcl], variants: [[true, true]]}
model: {lstm_hidden: 8, mlp_hidden: 16}
data: {decimate: 2, window: 20, test_fraction: 0.2, val_fraction: 0.1, seed: 0, cutoff_hz: 10.0,
       tau_filter_hz: 5.0}
train: {max_epochs: 3, batch_size: 8, seed: 0, device: cpu}
"""


@pytest.fixture(scope="module")
def local_ray():
    import sys

    from ray import cloudpickle

    from proprio.tasks import init_ray
    cloudpickle.register_pickle_by_value(sys.modules[__name__])   # workers cannot import this test module
    init_ray(num_cpus=2)
    yield ray
    ray.shutdown()


def _square(x: int, offset: Shared | int = 0, log: str | None = None) -> dict:
    if log:                                             # count executions across processes
        with open(log, "a") as f:
            f.write(f"{x}\n")
    if x == 3:
        raise RuntimeError("three is not allowed")
    return {"y": x * x + offset}


def _tasks(log: Path) -> list[Task]:
    off = Shared(10)
    return [Task(f"sq:{x}", _square, {"x": x, "offset": off, "log": str(log)}, {"x": x, "seed": x}) for x in range(5)]


@pytest.mark.parametrize("backend", ["local", "ray"])
def test_failure_is_reported_with_its_config_and_a_rerun_runs_only_what_is_missing(backend, tmp_path, request):
    if backend == "ray":
        request.getfixturevalue("local_ray")
    log = tmp_path / "log.txt"
    run = run_tasks(_tasks(log), tmp_path / "state", backend=backend, progress=False)
    assert run.records == {f"sq:{x}": {"y": x * x + 10} for x in (0, 1, 2, 4)}
    assert [f.key for f in run.failures] == ["sq:3"]
    f = run.failures[0]
    assert f.config == {"x": 3, "seed": 3} and "three is not allowed" in f.error and "RuntimeError" in f.error
    assert '"x": 3' in f.line() and "three is not allowed" in f.traceback
    assert len(list((tmp_path / "state").glob("*.failed.json"))) == 1
    # "kill" after some tasks: drop one finished result; the rerun runs it and the failed one, nothing else
    done = sorted((tmp_path / "state").glob("sq_1-*.json"))
    assert len(done) == 1
    done[0].unlink()
    log.write_text("")
    rerun = run_tasks(_tasks(log), tmp_path / "state", backend=backend, progress=False)
    assert sorted(log.read_text().split()) == ["1", "3"]
    assert rerun.executed == ["sq:1"] and rerun.skipped == ["sq:0", "sq:2", "sq:4"]
    assert rerun.records == run.records


def test_a_changed_config_is_not_taken_as_done(tmp_path):
    log = tmp_path / "log.txt"
    run_tasks(_tasks(log)[:2], tmp_path / "state", progress=False)
    changed = [Task(t.key, t.fn, t.kwargs, {**t.config, "seed": 99}) for t in _tasks(log)[:2]]
    assert run_tasks(changed, tmp_path / "state", progress=False).executed == ["sq:0", "sq:1"]


def test_engine_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="backend"):
        run_tasks([], tmp_path, backend="dask")
    with pytest.raises(ValueError, match="--address needs --backend ray"):
        run_tasks([], tmp_path, address="auto")
    t = Task("same", _square, {"x": 1})
    with pytest.raises(ValueError, match="unique"):
        run_tasks([t, t], tmp_path)


def test_dataset_is_identical_on_ray_and_local(local_ray, tmp_path, capsys):
    from proprio.recording import load_recording

    args = ["dataset", "--seeds", "1-2", "--scaffolds", "1", "--seconds", "2", "--log-rate", "200", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "local")]) == 0
    assert main(args + ["--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    ml = json.loads((tmp_path / "local" / "manifest.json").read_text())
    mr = json.loads((tmp_path / "ray" / "manifest.json").read_text())
    assert [r["file"] for r in ml["recordings"]] == ["rfma_s1_p0kg.npz", "rfma_s2_p0kg.npz"]
    assert [r["data_sha256"] for r in ml["recordings"]] == [r["data_sha256"] for r in mr["recordings"]]
    assert ml["twin"]["config_sha256"] == mr["twin"]["config_sha256"] and ml["twin"]["name"] == "iiwa14_twin"
    assert ml["recordings"][0]["trajectory_seed"] == 1 and ml["recordings"][1]["twin_seed"] == 2
    for r in ml["recordings"]:
        a, b = load_recording(tmp_path / "local" / r["file"]), load_recording(tmp_path / "ray" / r["file"])
        for name in ("t", "q", "tau", "qd", "f_ext"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.truth.keys() == b.truth.keys()
        assert all(np.array_equal(a.truth[k], b.truth[k]) for k in a.truth)
    a, b = (load_recording(tmp_path / d / "rfma_s1_p0kg.npz") for d in ("local", "ray"))
    assert not np.array_equal(a.tau[:100], load_recording(tmp_path / "local" / "rfma_s2_p0kg.npz").tau[:100])
    # resume: nothing left to do
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    assert "0 task(s) run, 2 already done" in capsys.readouterr().out


def _bench_rows(path: Path) -> list[dict]:
    rows = json.loads(path.read_text())["cases"]
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]


def test_gap_benchmark_on_ray_equals_local(local_ray, tmp_path):
    """One case of the --quick list, run locally and as a Ray task: the same scores, the withheld effect named."""
    cases = ["--quick", "--cases", "viscous_coulomb@1"]
    assert main(["gap-benchmark", *cases, "--out", str(tmp_path / "local"), "--workers", "1"]) == 0
    assert main(["gap-benchmark", *cases, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    local, on_ray = _bench_rows(tmp_path / "local" / "benchmark.json"), _bench_rows(tmp_path / "ray" / "benchmark.json")
    assert [r["case"] for r in local] == ["viscous_coulomb@1"] and local == on_ray
    assert local[0]["top"][0] == "viscous_coulomb" and not local[0]["error"]


@pytest.mark.slow
def test_gap_benchmark_on_ray_equals_local_and_resumes(local_ray, tmp_path, capsys):
    """Two cases of the --quick list (--cases), as the 15 quick cases take ≈2 min on 2 cores; a run killed after one
    case resumes with the other only."""
    cases = ["--quick", "--cases", "viscous_coulomb@1", "null#0"]
    assert main(["gap-benchmark", *cases, "--out", str(tmp_path / "local"), "--workers", "1"]) == 0
    assert main(["gap-benchmark", *cases, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    local, on_ray = _bench_rows(tmp_path / "local" / "benchmark.json"), _bench_rows(tmp_path / "ray" / "benchmark.json")
    assert [r["case"] for r in local] == ["viscous_coulomb@1", "null#0"]
    assert local == on_ray
    assert local[0]["top"][0] == "viscous_coulomb" and not local[0]["error"]
    # a run killed after one case: its result file exists, the other's not; the rerun finishes only that one
    kept = next((tmp_path / "ray" / "cases").glob("viscous_coulomb@1-*.json"))
    before = kept.read_text()
    next((tmp_path / "ray" / "cases").glob("null_0-*.json")).unlink()
    capsys.readouterr()
    assert main(["gap-benchmark", *cases, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    assert "1 task(s) run, 1 already done, 0 failed" in capsys.readouterr().err
    assert kept.read_text() == before
    assert _bench_rows(tmp_path / "ray" / "benchmark.json") == local


def test_unknown_case_and_address_without_ray_are_one_line_errors(tmp_path, capsys):
    assert main(["gap-benchmark", "--cases", "nope@1", "--out", str(tmp_path)]) == 2
    assert "unknown benchmark case(s) ['nope@1']" in capsys.readouterr().err
    assert main(["gap-benchmark", "--address", "auto", "--out", str(tmp_path)]) == 2
    assert "--address needs --backend ray" in capsys.readouterr().err


def test_train_grid_on_ray_equals_local(local_ray, tmp_path):
    import torch

    from proprio.learning.models import load_model

    assert main(["dataset", "--seeds", "1-2", "--scaffolds", "1", "--seconds", "3", "--log-rate", "200", "--quiet",
                 "--out", str(tmp_path / "data")]) == 0
    (tmp_path / "grid.yaml").write_text(GRID_YAML)
    data = [str(tmp_path / "data" / f"rfma_s{s}_p0kg.npz") for s in (1, 2)]
    common = ["train-grid", "--config", str(tmp_path / "grid.yaml"), "--data", *data]
    assert main([*common, "--out", str(tmp_path / "local")]) == 0
    assert main([*common, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    for tag in ("mlp7_hybrid_r", "lstm2_fcl_hybrid_r"):
        (a, _), (b, _) = (load_model(tmp_path / d / f"{tag}.pt") for d in ("local", "ray"))
        sa, sb = a.state_dict(), b.state_dict()
        assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa), tag
    gl, gr = (json.loads((tmp_path / d / "grid.json").read_text()) for d in ("local", "ray"))
    assert gl["rows"] == gr["rows"] and len(gl["rows"]) == 3
    assert gr["tasks"]["trained"] == ["mlp7_hybrid_r", "lstm2_fcl_hybrid_r"] and gr["tasks"]["backend"] == "ray"
    # rerun after losing one model: only that one is trained again, to the same weights
    (tmp_path / "ray" / "mlp7_hybrid_r.pt").unlink()
    assert main([*common, "--out", str(tmp_path / "ray"), "--backend", "ray"]) == 0
    gr2 = json.loads((tmp_path / "ray" / "grid.json").read_text())
    assert gr2["tasks"]["trained"] == ["mlp7_hybrid_r"] and gr2["rows"] == gl["rows"]


def test_device_cuda_without_a_gpu_is_a_one_line_error(tmp_path, capsys):
    import torch
    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA device")
    assert main(["train-grid", "--data", str(tmp_path / "x.npz"), "--out", str(tmp_path), "--device", "cuda"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("proprio: error: --device cuda: torch sees no CUDA device") and "\n" not in err
    from proprio.learning.training import pick_device
    assert pick_device("auto").type == "cpu"
