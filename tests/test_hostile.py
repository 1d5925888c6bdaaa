"""The hostile-input corpus (issue 26): bad files, bad configs and bad numbers across every command. Each case is
``(command line, words the message must name)``; each must end in exit code 2 with exactly one line
``proprio: error: …`` on stderr that names the offending field or file, no traceback and no output file.

The bad inputs are made in a temporary folder from one small valid recording; every case fails before any long
work (argument checks, output checks, loaders), so the corpus runs in-process (``proprio.cli.main``) in seconds.
"""
from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from proprio.cli import main
from proprio.effects.plugins import ALLOW_ENV

ROBOT = "iiwa14_nominal"
N = 7


# --------------------------------------------------------------------------------------------------------------------
# the bad files: made once per session from one valid 3 s recording
# --------------------------------------------------------------------------------------------------------------------
def _good(seconds: float = 3.0) -> dict:
    from proprio.description import load_robot
    from proprio.gap_benchmark.case_data import rfma_like_motion
    from proprio.dynamics import inverse_dynamics

    robot = load_robot(ROBOT)
    t, q, qd, qdd, _ = rfma_like_motion(robot, 1, seconds)
    return {"t": t, "q": q, "tau": inverse_dynamics(robot, q, qd, qdd), "meta": np.array(json.dumps({"robot": ROBOT}))}


def _npz(path: Path, **arrays) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _recordings(d: Path, g: dict) -> None:
    """Bad Recordings, one file each (the name says what is wrong)."""
    def rec(name: str, **changes):
        data = {**g, **changes}
        _npz(d / f"{name}.npz", **{k: v for k, v in data.items() if v is not None})

    q, tau, t = g["q"], g["tau"], g["t"]
    nan_q = q.copy()
    nan_q[10, 2] = np.nan
    inf_tau = tau.copy()
    inf_tau[5, 0] = np.inf
    dup = t.copy()
    dup[20:30] = dup[20]
    jump = t.copy()
    jump[50:] -= 1.0
    rec("nan_q", q=nan_q)
    rec("inf_tau", tau=inf_tau)
    rec("nan_t", t=np.where(np.arange(t.size) == 3, np.nan, t))
    rec("reversed_t", t=t[::-1].copy())
    rec("backward_t", t=jump)
    rec("degrees_q", q=np.degrees(q))
    rec("six_joints", q=q[:, :6].copy(), tau=tau[:, :6].copy())
    rec("short_tau", tau=tau[:-5].copy())
    rec("flat_q", q=q[:, 0].copy())
    rec("no_samples", t=t[:0], q=q[:0], tau=tau[:0])
    rec("no_tau", tau=None)
    rec("no_q", q=None)
    rec("text_q", q=q.astype(str))
    rec("complex_tau", tau=tau.astype(complex))
    rec("bad_meta", meta=np.array("{not json"))
    rec("tau_3d", tau=tau[:, :, None].copy())
    rec("qd_wrong_shape", qd=np.zeros((t.size, 3)))
    rec("f_ext_wrong_shape", f_ext=np.zeros((t.size, 5)))
    with open(d / "pickled.npz", "wb") as fh:                           # an object array: a pickle inside the .npz
        np.savez(fh, t=t, q=np.array([object()] * 3, dtype=object), tau=tau)
    good = (d / "good.npz").read_bytes()
    (d / "truncated.npz").write_bytes(good[: len(good) // 2])
    (d / "empty.npz").write_bytes(b"")
    (d / "text.npz").write_text("t,q1\n0,1\n")
    (d / "raw_pickle.npz").write_bytes(pickle.dumps({"t": t}))
    (d / "folder.npz").mkdir()


def _csvs(d: Path, g: dict) -> None:
    header = ["t"] + [f"q{i + 1}" for i in range(N)] + [f"tau{i + 1}" for i in range(N)]
    rows = np.column_stack([g["t"], g["q"], g["tau"]])
    body = "\n".join(",".join(f"{x:.6g}" for x in r) for r in rows)
    (d / "good.csv").write_text(",".join(header) + "\n" + body + "\n")
    lines = body.split("\n")
    cells = lines[100].split(",")
    (d / "text_cell.csv").write_text(",".join(header) + "\n" + "\n".join(
        lines[:100] + [",".join(cells[:3] + ["abc"] + cells[4:])] + lines[101:]) + "\n")
    (d / "semicolon.csv").write_text(";".join(header) + "\n" + "\n".join(
        ";".join(f"{x:.6g}".replace(".", ",") for x in r) for r in rows) + "\n")
    (d / "no_tau.csv").write_text(",".join(header[:8]) + "\n" + "\n".join(
        ",".join(f"{x:.6g}" for x in r[:8]) for r in rows) + "\n")
    (d / "header_only.csv").write_text(",".join(header) + "\n")
    (d / "empty.csv").write_text("")
    (d / "reversed.csv").write_text(",".join(header) + "\n" + "\n".join(reversed(lines)) + "\n")
    (d / "extra_field.csv").write_text(",".join(header) + "\n" + "\n".join(         # every row but 4 one field long
        line + (",9" if k >= 4 else "") for k, line in enumerate(lines)) + "\n")


def _models(d: Path) -> None:
    """Bad model files for --model / --backbone (identified .npz, hybrid .pt)."""
    import torch

    _npz(d / "model_wrong_keys.npz", a=np.zeros(3))
    with open(d / "model_pickled.npz", "wb") as fh:
        np.savez(fh, phi_b=np.array([object()], dtype=object))
    (d / "model_truncated.npz").write_bytes((d / "good.npz").read_bytes()[:200])
    (d / "model_garbage.pt").write_bytes(b"\x00not a torch file" * 10)
    torch.save({"state_dict": {"w": torch.zeros(2)}, "config": {"arch": "nope"}}, d / "model_wrong_state.pt")
    torch.save({"payload": Exploit()}, d / "model_exploit.pt")              # refused by weights_only
    good = (d / "model_wrong_state.pt").read_bytes()
    (d / "model_truncated.pt").write_bytes(good[: len(good) // 3])
    (d / "model_empty.pt").write_bytes(b"")
    demo = torch.load(Path(__file__).parents[1] / "proprio" / "configs" / "demo_residual.pt", weights_only=True)
    torch.save({**demo, "state_dict": {"w": torch.zeros(2)}}, d / "model_foreign_state.pt")   # right format tag
    (d / "ckpt_exploit").mkdir()
    torch.save({"payload": Exploit()}, d / "ckpt_exploit" / "m.pt.ckpt")   # a checkpoint weights_only refuses


class Exploit:
    """An object a tampered checkpoint would unpickle (never: torch.load(weights_only=True) refuses it)."""

    def __reduce__(self):
        return (print, ("exploit ran",))


def _yaml(d: Path, name: str, data) -> None:
    (d / name).write_text(data if isinstance(data, str) else yaml.safe_dump(data))


def _configs(d: Path) -> None:
    base = {"name": "t", "robot": "iiwa14_identified"}
    twins = {
        "twin_syntax": "name: [unclosed\nrobot: x\n",
        "twin_list": "- robot\n- effects\n",
        "twin_scalar": "just a string\n",
        "twin_python_tag": "!!python/object/apply:os.system ['echo hi']\n",
        "twin_no_robot": {"name": "x"},
        "twin_unknown_robot": {**base, "robot": "no_such_robot_xyz"},
        "twin_effects_list": {**base, "effects": ["hysteresis"]},
        "twin_effect_unknown": {**base, "effects": {"hysterisis": {}}},
        "twin_effect_block_list": {**base, "effects": {"torque_noise": [1, 2]}},
        "twin_plugin_unregistered": {**base, "effects": {"os:system": {}}},
        "twin_plugin_relative": {**base, "effects": {".evil:Boom": {}}},
        "twin_plugin_bad_syntax": {**base, "effects": {"a b:C": {}}},
        "twin_kp_short": {**base, "controller": {"kp": [1, 2, 3]}},
        "twin_kp_negative": {**base, "controller": {"kp": -5}},
        "twin_controller_unknown": {**base, "controller": {"kpp": 3}},
        "twin_time_step": {**base, "time_step": -1},
        "twin_session_word": {**base, "session_time_s": "later"},
        "twin_logger_rate": {**base, "logger": {"rate_hz": 0}},
        "twin_logger_channel": {**base, "logger": {"channels": ["q", "torque"]}},
        "twin_payload_negative": {**base, "payload": {"mass": -2}},
        "twin_elastic_no_drive": {**base, "effects": {"elasticity": {}}},
        "twin_effect_word": {**base, "effects": {"torque_noise": {"std": "abc"}}},
        "twin_effect_short": {**base, "effects": {"hysteresis": {"saturation": [1, 2]}}},
        "twin_effect_field_typo": {**base, "effects": {"torque_noise": {"sdt": 0.1}}},
    }
    for name, data in twins.items():
        _yaml(d, f"{name}.yaml", data)
    target = {"robot": "iiwa14_identified", "joints": N}
    patches = {
        "patch_list": "- effects\n",
        "patch_syntax": "effects: {a: [\n",
        "patch_no_target": {"effects": {"torque_noise": {"std": 0.1}}},
        "patch_other_robot": {"patch_for": {"robot": "kuka_lwr4plus", "joints": 7}, "effects": {}},
        "patch_unknown_key": {"patch_for": target, "efects": {}},
        "patch_plugin": {"patch_for": target, "effects": {"os.path:join": {}}},
        "patch_effect_twice": {"patch_for": target, "effects": {"hysteresis": {}}},
    }
    for name, data in patches.items():
        _yaml(d, f"{name}.yaml", data)
    effects = {
        "effects_syntax": "effects: {\n",
        "effects_list": "- hysteresis\n",
        "effects_unknown": {"effects": {"hysterisis": {}}},
        "effects_plugin": {"effects": {"os:system": {}}},
    }
    for name, data in effects.items():
        _yaml(d, f"{name}.yaml", data)
    _yaml(d, "train_syntax.yaml", "model: [\n")
    _yaml(d, "train_list.yaml", "- a\n")
    _yaml(d, "rfma_syntax.yaml", "scaffolds: [\n")
    _yaml(d, "robot_syntax.yaml", "name: [\n")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("hostile")
    g = _good()
    _npz(d / "good.npz", **g)
    _npz(d / "long.npz", **_good(8.0))             # long enough for a diagnosis without --holdout
    _recordings(d, g)
    _csvs(d, g)
    _models(d)
    _configs(d)
    (d / "a_file").write_text("x")
    (d / "a_dir").mkdir()
    (d / "a_dir.npz").mkdir()
    (d / "a_dir.html").mkdir()
    (d / "a_dir.png").mkdir()
    (d / "a_dir.pt").mkdir()
    return d


# --------------------------------------------------------------------------------------------------------------------
# the cases: {d} is the folder of the bad files, {o} a fresh output folder per case
# --------------------------------------------------------------------------------------------------------------------
def _reading_commands(f: str) -> dict[str, str]:
    """Every command that reads a Recording, reading ``f`` on its cheapest path."""
    return {
        "inspect": f"inspect {f} --robot {ROBOT}",
        "identify": f"identify --robot {ROBOT} --train {f} --out {{o}}/m.npz",
        "diagnose": f"diagnose --model {ROBOT} --train {f} --out {{o}}/d",
        "estimate": f"estimate --model {ROBOT} --recording {f} --out {{o}}/e",
        "view": f"view {f} --model {ROBOT} --html {{o}}/v.html",
        "train": f"train --config train_demo --backbone {ROBOT} --data {f} --out {{o}}/m.pt",
        "replay": f"simulate --twin iiwa14_nominal_twin --replay {f} --out {{o}}/r.npz",
    }


BAD_RECORDINGS = {      # file → words its message must name (besides the file)
    "nan_q": "NaN|nan", "inf_tau": "inf", "nan_t": "NaN|nan", "reversed_t": "increasing", "backward_t": "increasing",
    "degrees_q": "degree", "six_joints": "6 joints", "short_tau": "tau", "flat_q": "q", "no_samples": "sample",
    "no_tau": "tau", "no_q": "q", "text_q": "q", "complex_tau": "tau", "bad_meta": "meta", "tau_3d": "tau",
    "qd_wrong_shape": "qd", "f_ext_wrong_shape": "f_ext", "pickled": "pickled Python objects",
    "truncated": "truncated|corrupt", "empty": "truncated|corrupt|empty", "text": "truncated|corrupt|npz",
    "raw_pickle": "pickled Python objects",
    "folder": "directory|folder|file", "missing": "no such file|not found",
}

CASES: list[tuple[str, str, str]] = []
for _bad, _word in BAD_RECORDINGS.items():
    for _cmd, _line in _reading_commands(f"{{d}}/{_bad}.npz").items():
        # the file is named, except where a model check runs after loading (it names the channel and the robot)
        _named = _word if _bad == "six_joints" else f"{_bad}\\.npz.*({_word})|({_word}).*{_bad}\\.npz"
        CASES.append((f"{_cmd}-{_bad}", _line, _named))

for _bad, _word in {"text_cell": "'abc' is not a number", "no_tau": "tau1", "header_only": "0 sample",
                    "reversed": "increasing", "missing": "no such file",
                    "extra_field": r"line 6 has 16 fields where the header has 15; \d+ more"}.items():
    CASES.append((f"inspect-csv-{_bad}", f"inspect {{d}}/{_bad}.csv", _word))

NUMBERS = [   # (command line, flag named)
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --payload-kg nan", "--payload-kg"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --payload-kg inf", "--payload-kg"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --payload-kg -1", "--payload-kg"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --payload-kg abc", "--payload-kg"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --payload-com 0 nan 0", "--payload-com"),
    ("simulate --replay {d}/good.npz --out {o}/s.npz --trim -5", "--trim"),
    ("simulate --replay {d}/good.npz --out {o}/s.npz --trim nan", "--trim"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --seconds 0", "--seconds"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --seconds -3", "--seconds"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --seconds nan", "--seconds"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --log-rate 0", "--log-rate"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --log-rate inf", "--log-rate"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --seed -1", "--seed"),
    ("simulate --trajectory {d}/good.npz --out {o}/s.npz --seed 1.5", "--seed"),
    ("dataset --seeds 1 --out {o}/ds --payload-kg nan", "--payload-kg"),
    ("dataset --seeds 1 --out {o}/ds --payload-kg -1", "--payload-kg"),
    ("dataset --seeds 1 --out {o}/ds --scaffolds 0", "--scaffolds"),
    ("dataset --seeds 1 --out {o}/ds --seconds -1", "--seconds"),
    ("dataset --seeds 1 --out {o}/ds --log-rate 0", "--log-rate"),
    ("dataset --seeds 1 --out {o}/ds --twin-seed -2", "--twin-seed"),
    ("dataset --seeds 1 --out {o}/ds --workers 0", "--workers"),
    ("dataset --seeds 1 --out {o}/ds --workers -4", "--workers"),
    ("dataset --seeds=-5 --out {o}/ds", "seed"),
    ("dataset --seeds abc --out {o}/ds", "seed"),
    ("dataset --seeds 5-3 --out {o}/ds", "seed"),
    ("train --data {d}/good.npz --out {o}/m.pt --threads 0", "--threads"),
    ("train --data {d}/good.npz --out {o}/m.pt --threads -1", "--threads"),
    ("train --data {d}/good.npz --out {o}/m.pt --threads x", "--threads"),
    ("train-grid --data {d}/good.npz --out {o}/g --threads 0", "--threads"),
    ("train-grid --data {d}/good.npz --out {o}/g --epochs 0", "--epochs"),
    ("train-grid --data {d}/good.npz --out {o}/g --search -1", "--search"),
    ("train-grid --data {d}/good.npz --out {o}/g --search 2", "--search"),
    ("train-grid --data {d}/good.npz --out {o}/g --workers 0", "--workers"),
    ("evaluate --model {d}/model_garbage.pt --data {d}/good.npz --threads 0", "--threads"),
    ("estimate --recording {d}/good.npz --out {o}/e --gain 0", "--gain"),
    ("estimate --recording {d}/good.npz --out {o}/e --gain nan", "--gain"),
    ("estimate --recording {d}/good.npz --out {o}/e --sigma-threshold -1", "--sigma-threshold"),
    ("estimate --recording {d}/good.npz --out {o}/e --cutoff-hz -3", "--cutoff-hz"),
    ("estimate --recording {d}/good.npz --out {o}/e --cutoff-hz abc", "--cutoff-hz"),
    ("estimate --recording {d}/good.npz --out {o}/e --cutoff-hz nan", "--cutoff-hz"),
    ("payload-experiment --out {o}/p --seconds 0", "--seconds"),
    ("payload-experiment --out {o}/p --seconds nan", "--seconds"),
    ("payload-experiment --out {o}/p --masses 0 -1", "--masses"),
    ("payload-experiment --out {o}/p --masses nan", "--masses"),
    ("payload-experiment --out {o}/p --seed -1", "--seed"),
    ("diagnose --model iiwa14_nominal --train {d}/good.npz --out {o}/d --cutoff-hz 0", "--cutoff-hz"),
    ("diagnose --model iiwa14_nominal --train {d}/good.npz --out {o}/d --cutoff-hz abc", "--cutoff-hz"),
    ("diagnose --model iiwa14_nominal --train {d}/good.npz --out {o}/d --cutoff-hz nan", "--cutoff-hz"),
    ("diagnose --model iiwa14_nominal --train {d}/good.npz --out {o}/d --trim -5", "--trim"),
    ("diagnose --model iiwa14_nominal --train {d}/good.npz --out {o}/d --trim inf", "--trim"),
    ("view {d}/good.npz --html {o}/v.html --fps 0", "fps"),
    ("view {d}/good.npz --html {o}/v.html --max-frames 0", "max-frames"),
    ("view {d}/good.npz --html {o}/v.html --force-scale nan", "force-scale"),
    ("view {d}/good.npz --html {o}/v.html --start nan", "--start"),
    ("view {d}/good.npz --html {o}/v.html --serve-seconds -1", "--serve-seconds"),
    ("view {d}/good.npz --html {o}/v.html --cutoff-hz -1", "--cutoff-hz"),
    ("identify --robot iiwa14_nominal --train {d}/good.npz --out {o}/m.npz --trim -1", "--trim"),
    ("identify --robot iiwa14_nominal --train {d}/good.npz --out {o}/m.npz --coulomb-velocity-scale -1",
     "--coulomb-velocity-scale"),
    ("identify --robot iiwa14_nominal --train {d}/good.npz --out {o}/m.npz --method magic", "--method"),
    ("excite --out {o}/x.npz --starts 0", "--starts"),
    ("excite --out {o}/x.npz --seed -1", "--seed"),
    ("trajectory rfma --out {o}/t.npz --scaffolds 0", "--scaffolds"),
    ("trajectory rfma --out {o}/t.npz --seed -7", "--seed"),
    ("trajectory plot {d}/good.npz --rate 0", "--rate"),
    ("inspect {d}/good.npz --deadband -1", "--deadband"),
    ("inspect {d}/good.npz --angle-unit grad", "--angle-unit"),
    ("gap-benchmark --out {o}/b --seed -1", "--seed"),
    ("gap-benchmark --out {o}/b --workers 0", "--workers"),
    ("gap-benchmark --out {o}/b --address 10.0.0.1:6379", "--address"),
    ("gap-benchmark --out {o}/b --backend ray --address 127.0.0.1:1", "--address"),
    ("gap-benchmark --out {o}/b --backend ray --address nowhere", "--address"),
    ("dataset --seeds 1 --out {o}/ds --backend ray --address ray://127.0.0.1:1", "--address"),
    ("gap-benchmark --out {o}/b --cases no_such_case", "no_such_case"),
]
for _line, _flag in NUMBERS:
    CASES.append((f"number-{_line.split()[0]}-{_flag}-{len(CASES)}", _line, re.escape(_flag)))

OUTPUTS = [   # (command line with OUT, flag): OUT is an existing folder where a file goes, or the reverse
    ("simulate --trajectory {d}/good.npz --out OUT.npz", "--out", "dir"),
    ("twin hysteresis-test --out OUT", "--out", "file"),
    ("diagnose --model iiwa14_nominal --train {d}/good.npz --out OUT", "--out", "file"),
    ("gap-benchmark --quick --out OUT", "--out", "file"),
    ("dataset --seeds 1 --out OUT", "--out", "file"),
    ("estimate --recording {d}/good.npz --out OUT", "--out", "file"),
    ("payload-experiment --out OUT", "--out", "file"),
    ("identify --robot iiwa14_nominal --train {d}/good.npz --out OUT.npz", "--out", "dir"),
    ("excite --out OUT.npz", "--out", "dir"),
    ("inspect {d}/good.npz --plot OUT.png", "--plot", "dir"),
    ("view {d}/good.npz --html OUT.html", "--html", "dir"),
    ("train --data {d}/good.npz --out OUT.pt", "--out", "dir"),
    ("train-grid --data {d}/good.npz --out OUT", "--out", "file"),
    ("trajectory rfma --out OUT.npz", "--out", "dir"),
    ("trajectory plot {d}/good.npz --out OUT.png", "--out", "dir"),
    ("demo --out OUT", "--out", "file"),
]
for _line, _flag, _kind in OUTPUTS:
    _cmd = _line.split()[0] + ("-" + _line.split()[1] if _line.split()[0] in ("twin", "trajectory") else "")
    _wrong = "{d}/a_dir" if _kind == "dir" else "{d}/a_file"
    CASES.append((f"output-exists-{_cmd}", _line.replace("OUT", _wrong), re.escape(_flag)))
    CASES.append((f"output-parent-is-file-{_cmd}", _line.replace("OUT", "{d}/a_file/sub"), re.escape(_flag)))
    CASES.append((f"output-read-only-{_cmd}", _line.replace("OUT", "/proc/proprio_hostile"), re.escape(_flag)))

MODEL_FILES = {"model_wrong_keys.npz": "model_wrong_keys", "model_pickled.npz": "model_pickled",
               "model_truncated.npz": "model_truncated", "model_garbage.pt": "model_garbage",
               "model_wrong_state.pt": "model_wrong_state", "model_exploit.pt": "model_exploit.*pickled Python",
               "model_truncated.pt": "model_truncated", "model_empty.pt": "model_empty",
               "model_foreign_state.pt": "model_foreign_state.*do not fit",
               "no_such_model.npz": "no_such_model", "no_such_robot_xyz": "no_such_robot_xyz",
               "robot_syntax.yaml": "robot_syntax"}
for _file, _word in MODEL_FILES.items():
    _m = _file if "." not in _file or _file.startswith("no_such_robot") else f"{{d}}/{_file}"
    CASES.append((f"estimate-model-{_file}", f"estimate --model {_m} --recording {{d}}/good.npz --out {{o}}/e",
                   _word))
    if _file.endswith(".pt"):
        CASES.append((f"evaluate-model-{_file}", f"evaluate --model {_m} --data {{d}}/good.npz", _word))
        CASES.append((f"view-model-{_file}", f"view {{d}}/good.npz --model {_m} --html {{o}}/v.html", _word))
    if _file.endswith(".npz"):
        CASES.append((f"train-backbone-{_file}",
                      f"train --config train_demo --backbone {_m} --data {{d}}/good.npz --out {{o}}/m.pt", _word))
    if not _file.endswith(".pt"):
        CASES.append((f"diagnose-model-{_file}", f"diagnose --model {_m} --train {{d}}/good.npz --out {{o}}/d",
                      _word))
        CASES.append((f"identify-robot-{_file}", f"identify --robot {_m} --train {{d}}/good.npz --out {{o}}/m.npz",
                      _word))

TWIN_WORDS = {
    "twin_syntax": "twin_syntax", "twin_list": "mapping", "twin_scalar": "mapping", "twin_python_tag": "python",
    "twin_no_robot": "robot", "twin_unknown_robot": "no_such_robot_xyz", "twin_effects_list": "effects",
    "twin_effect_unknown": "hysterisis", "twin_effect_block_list": "torque_noise",
    "twin_plugin_unregistered": "os:system", "twin_plugin_relative": ".evil:Boom", "twin_plugin_bad_syntax": "a b:C",
    "twin_kp_short": "kp", "twin_kp_negative": "kp", "twin_controller_unknown": "kpp", "twin_time_step": "time_step",
    "twin_session_word": "session_time_s", "twin_logger_rate": "rate_hz", "twin_logger_channel": "torque",
    "twin_payload_negative": "payload", "twin_elastic_no_drive": "drive", "twin_effect_word": "torque_noise.std",
    "twin_effect_short": "hysteresis.saturation", "twin_effect_field_typo": "sdt",
}
for _twin, _word in TWIN_WORDS.items():
    _t = f"{{d}}/{_twin}.yaml"
    CASES.append((f"simulate-{_twin}", f"simulate --twin {_t} --trajectory {{d}}/good.npz --seconds 0.05 "
                  "--out {o}/s.npz", re.escape(_word)))
    CASES.append((f"dataset-{_twin}", f"dataset --twin {_t} --seeds 1 --scaffolds 1 --seconds 0.05 --out {{o}}/ds",
                  re.escape(_word)))
    CASES.append((f"hysteresis-test-{_twin}", f"twin hysteresis-test --twin {_t} --out {{o}}/h", re.escape(_word)))
CASES.append(("simulate-no-such-twin", "simulate --twin {d}/nope.yaml --trajectory {d}/good.npz --out {o}/s.npz",
              "nope"))
CASES.append(("payload-experiment-twin-syntax", "payload-experiment --twin-config {d}/twin_syntax.yaml --out {o}/p",
              "twin_syntax"))
CASES.append(("diagnose-twin-unknown-effect", "diagnose --model iiwa14_identified --train {d}/good.npz --holdout "
              "{d}/good.npz --twin {d}/twin_effect_unknown.yaml --out {o}/d", "hysterisis"))

PATCH_WORDS = {"patch_list": "mapping", "patch_syntax": "patch_syntax", "patch_no_target": "patch_for",
               "patch_other_robot": "patch_for", "patch_unknown_key": "efects", "patch_plugin": "os.path:join",
               "patch_effect_twice": "hysteresis", "no_such_patch": "no_such_patch"}
for _patch, _word in PATCH_WORDS.items():
    CASES.append((f"simulate-{_patch}", f"simulate --patch {{d}}/{_patch}.yaml --trajectory {{d}}/good.npz "
                  "--out {o}/s.npz", re.escape(_word)))

EFFECTS_WORDS = {"effects_syntax": "effects_syntax", "effects_list": "effects", "effects_unknown": "hysterisis",
                 "effects_plugin": "os:system", "no_such_effects": "no_such_effects"}
for _eff, _word in EFFECTS_WORDS.items():
    CASES.append((f"diagnose-{_eff}", f"diagnose --model iiwa14_nominal --effects torque_noise --effects-config "
                  f"{{d}}/{_eff}.yaml --train {{d}}/good.npz --out {{o}}/d", re.escape(_word)))
CASES += [
    ("diagnose-effects-unknown", "diagnose --model iiwa14_nominal --effects hysterisis --train {d}/good.npz "
     "--out {o}/d", "hysterisis"),
    ("diagnose-candidates-unknown", "diagnose --model iiwa14_nominal --candidates frition --train {d}/long.npz "
     "--out {o}/d", "frition"),
    ("diagnose-candidate-missing-module", "diagnose --model iiwa14_nominal --candidate no_such_mod_xyz:K "
     "--train {d}/good.npz --out {o}/d", "no_such_mod_xyz"),
    ("diagnose-candidate-relative", "diagnose --model iiwa14_nominal --candidate .rel:K --train {d}/good.npz "
     "--out {o}/d", "rel:K"),
    ("diagnose-one-log-too-short", "diagnose --model iiwa14_identified --twin iiwa14_twin --train {d}/good.npz "
     "--out {o}/d", "record ≥ .* s at this split.*--holdout REC"),
    ("train-checkpoint-refused-by-weights-only", "train --config train_demo --backbone iiwa14_nominal --data "
     "{d}/good.npz --out {d}/ckpt_exploit/m.pt", "m.pt.ckpt.*remove it.*pickled Python objects"),
    ("diagnose-friction-twice", "diagnose --model iiwa14_identified --effects viscous_coulomb --train "
     "{d}/good.npz --out {o}/d", "viscous_coulomb"),
    ("simulate-both-sources", "simulate --trajectory {d}/good.npz --replay {d}/good.npz --out {o}/s.npz",
     "--replay"),
    ("simulate-no-source", "simulate --out {o}/s.npz", "--trajectory"),
    ("simulate-trajectory-missing", "simulate --trajectory {d}/nope.npz --out {o}/s.npz", "nope"),
    ("simulate-trajectory-truncated", "simulate --trajectory {d}/truncated.npz --out {o}/s.npz", "truncated"),
    ("simulate-trajectory-pickled", "simulate --trajectory {d}/pickled.npz --out {o}/s.npz", "pickled"),
    ("simulate-trajectory-wrong-keys", "simulate --trajectory {d}/model_wrong_keys.npz --out {o}/s.npz",
     "model_wrong_keys"),
    ("simulate-replay-with-seed", "simulate --replay {d}/good.npz --seed 3 --out {o}/s.npz", "--seed"),
    ("simulate-allow-plugin-syntax", "simulate --trajectory {d}/good.npz --allow-plugin ../x:Y --out {o}/s.npz",
     "../x:Y"),
    ("train-config-missing", "train --config {d}/nope.yaml --data {d}/good.npz --out {o}/m.pt", "nope"),
    ("train-config-syntax", "train --config {d}/train_syntax.yaml --data {d}/good.npz --out {o}/m.pt",
     "train_syntax"),
    ("train-config-list", "train --config {d}/train_list.yaml --data {d}/good.npz --out {o}/m.pt", "train_list"),
    ("train-device-unknown", "train --device tpu --data {d}/good.npz --out {o}/m.pt", "--device"),
    ("train-grid-config-syntax", "train-grid --config {d}/train_syntax.yaml --data {d}/good.npz --out {o}/g",
     "train_syntax"),
    ("trajectory-plot-truncated", "trajectory plot {d}/truncated.npz --out {o}/p.png", "truncated"),
    ("trajectory-plot-missing", "trajectory plot {d}/nope.npz --out {o}/p.png", "nope"),
    ("trajectory-plot-recording", "trajectory plot {d}/good.npz --out {o}/p.png", "good.npz"),
    ("trajectory-rfma-config-syntax", "trajectory rfma --config {d}/rfma_syntax.yaml --out {o}/t.npz",
     "rfma_syntax"),
    ("trajectory-rfma-config-missing", "trajectory rfma --config {d}/nope.yaml --out {o}/t.npz", "nope"),
    ("trajectory-rfma-robot-unknown", "trajectory rfma --robot no_such_robot_xyz --out {o}/t.npz",
     "no_such_robot_xyz"),
    ("excite-robot-unknown", "excite --robot no_such_robot_xyz --out {o}/x.npz", "no_such_robot_xyz"),
    ("view-source-missing", "view {d}/nope.npz --html {o}/v.html", "nope"),
    ("view-window-empty", "view {d}/good.npz --model iiwa14_nominal --start 100 --html {o}/v.html", "window"),
    ("unknown-command", "frobnicate", "frobnicate"),
    ("unknown-flag", "inspect {d}/good.npz --frobnicate", "--frobnicate"),
]


@pytest.fixture(autouse=True)
def _no_leaked_consent(monkeypatch):
    monkeypatch.delenv(ALLOW_ENV, raising=False)


def _run(line: str, d: Path, o: Path, capsys) -> tuple[int, str, str]:
    code = main(line.format(d=d, o=o).split())
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_the_corpus_is_large():
    assert len(CASES) >= 200 and len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.parametrize("line,word", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_hostile_input_is_one_line_naming_it(files, tmp_path, capsys, line, word):
    out = tmp_path / "out"
    code, stdout, stderr = _run(line, files, out, capsys)
    lines = stderr.strip().splitlines()
    assert code == 2, stderr
    assert "Traceback" not in stderr + stdout
    assert len(lines) == 1 and lines[0].startswith("proprio: error: "), stderr
    assert len(lines[0]) < 2000, f"{len(lines[0])} characters"   # a list of valid names fits; a dump of every bad row not
    assert re.search(word, lines[0], re.IGNORECASE), f"{word!r} not named in: {lines[0]}"
    assert not "allow_pickle" in stderr and "weights_only" not in stderr
    assert not out.exists() or not any(out.rglob("*")), "partial output written"



def test_a_bug_keeps_its_traceback(monkeypatch):
    """Only user errors are one line: an exception that is not one (a bug) propagates with its traceback."""
    import proprio.cli.inspect as command

    def bug(args):
        raise KeyError("a bug in proprio")

    monkeypatch.setattr(command, "run", bug)
    with pytest.raises(KeyError, match="a bug in proprio"):
        main(["inspect", "whatever.npz"])


def test_a_loaders_pickle_advice_is_never_passed_on():
    from proprio.cli import _one_line

    numpy = ValueError("x.npz: not readable (Object arrays cannot be loaded when allow_pickle=False)")
    torch = ValueError("m.pt: not a readable model file (Weights only load failed. Re-running `torch.load` with "
                       "`weights_only` set to `False` will likely succeed)")
    for exc in (numpy, torch):
        line = _one_line(exc)
        assert "pickled Python objects, which proprio never loads" in line and line.count("(") == line.count(")")
        assert not re.search("allow_pickle|weights_only|Re-running", line), line
