"""One command line (issue 36): shared flags declared once (proprio/cli/flags.py) with one meaning and unit, list flags
that accumulate, diagnose's one-log split, output without carriage returns off a terminal, statistics printed where
announced, one check that a log is of the model's robot, and advice that works when followed (each suggested command
is run)."""
from __future__ import annotations

import argparse
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

from proprio.cli import build_parser, main
from proprio.cli.flags import _Accumulate

ROBOT = "iiwa14_nominal"


def _rec(path: Path, seconds: float, offset: np.ndarray | None = None, **meta) -> Path:
    from proprio.description import load_robot
    from proprio.gap_benchmark.case_data import rfma_like_motion
    from proprio.dynamics import inverse_dynamics

    robot = load_robot(ROBOT)
    t, q, qd, qdd, _ = rfma_like_motion(robot, 1, seconds)
    tau = inverse_dynamics(robot, q, qd, qdd) + (0.0 if offset is None else offset)
    tau = tau + 0.02 * np.random.default_rng(0).standard_normal(tau.shape)
    with open(path, "wb") as fh:
        np.savez(fh, t=t, q=q, tau=tau, meta=np.array(json.dumps({"robot": ROBOT, **meta})))
    return path


@pytest.fixture(scope="module")
def recs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("flags")
    _rec(d / "short.npz", 3.0)
    _rec(d / "long.npz", 9.0)
    _rec(d / "offset.npz", 9.0, offset=np.r_[0.8, np.zeros(6)])
    _rec(d / "free_text_tau.npz", 3.0, tau_kind="measured by the sensor")
    other = d / "other_arm"                         # another arm (its base moved), its robot.yaml beside its log
    other.mkdir()
    desc = yaml.safe_load((Path(__file__).parents[1] / "proprio" / "robots" / f"{ROBOT}.yaml").read_text())
    desc["name"] = "other_arm"
    desc["base"]["world_to_base_link"]["xyz"] = [0.3, 0.0, 0.0]
    (other / "robot.yaml").write_text(yaml.safe_dump(desc))
    _rec(other / "log.npz", 3.0, robot="other_arm")
    return d


def _subparsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield name, sub
                for inner, deeper in _subparsers(sub):
                    yield f"{name} {inner}", deeper


def _flag(sub: argparse.ArgumentParser, name: str):
    return next((a for a in sub._actions if name in a.option_strings), None)


COMMANDS = dict(_subparsers(build_parser()))


def test_every_list_flag_accumulates_when_repeated():
    lists = [(cmd, a.option_strings[0]) for cmd, sub in COMMANDS.items() for a in sub._actions
             if a.option_strings and a.nargs in ("+", "*")]
    assert len(lists) >= 12
    assert all(isinstance(_flag(COMMANDS[cmd], f), _Accumulate) for cmd, f in lists), lists
    args = build_parser().parse_args("diagnose --model m --train a --holdout h --train b c --out o".split())
    assert [str(p) for p in args.train] == ["a", "b", "c"] and [str(p) for p in args.holdout] == ["h"]
    args = build_parser().parse_args("dataset --seeds 1 --payload-kg 2 --payload-kg 3 --out o".split())
    assert args.payload_kg == [2.0, 3.0]                           # the default is replaced, not extended
    assert build_parser().parse_args("dataset --seeds 1 --out o".split()).payload_kg == [0.0]


def test_a_shared_flag_means_one_thing_in_every_command():
    from proprio.identification.recordings import TRIM_S

    where = {"--trim": {"identify", "diagnose", "simulate"},
             "--cutoff-hz": {"identify", "diagnose", "estimate", "payload-experiment", "view"},
             "--split-at": {"identify", "diagnose"}, "--holdout-fraction": {"identify", "diagnose"},
             "--quiet": {"simulate", "twin hysteresis-test", "dataset"},
             "--twin": {"simulate", "twin hysteresis-test", "dataset", "payload-experiment", "diagnose",
                        "gap-benchmark"}}
    for flag, commands in where.items():
        have = {cmd for cmd, sub in COMMANDS.items() if _flag(sub, flag)}
        assert have == commands, flag
        actions = [_flag(COMMANDS[c], flag) for c in commands - {"gap-benchmark"}]   # its --twin: a switch
        assert len({(a.type, a.metavar, type(a)) for a in actions}) == 1, flag     # one declaration
    assert all("seconds" in _flag(COMMANDS[c], "--trim").help for c in where["--trim"])
    assert f"default {TRIM_S:g}" in _flag(COMMANDS["identify"], "--trim").help
    assert _flag(COMMANDS["diagnose"], "--cutoff") is None
    args = build_parser().parse_args("identify --robot r --train a --out o --trim 0.25".split())
    assert args.trim == 0.25 and args.cutoff_hz == "auto"


@pytest.mark.parametrize("line", ["diagnose --model m --train a --out o --cutoff-hz 0",
                                  "identify --robot r --train a --out o --cutoff-hz nan",
                                  "identify --robot r --train a --out o --holdout-fraction 1",
                                  "diagnose --model m --train a --out o --split-at 3 --holdout-fraction 0.2"])
def test_bad_shared_values_are_one_line(line, capsys):
    assert main(line.split()) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("proprio: error: ")


@pytest.mark.parametrize("command", ["identify --robot iiwa14_nominal --out {o}/m.npz",
                                     "diagnose --model iiwa14_nominal --out {o}/d"])
def test_a_split_outside_the_log_names_the_flag(command, recs, tmp_path, capsys):
    assert main(command.format(o=tmp_path).split() + ["--train", str(recs / "short.npz"), "--split-at", "20"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--split-at 20 s leaves no sample" in err and "short.npz" in err


def test_a_log_too_short_to_decide_is_refused_up_front_with_the_seconds_it_needs(recs, tmp_path, capsys):
    from proprio.diagnosis.data import MIN_BLOCK_S, MIN_BLOCKS

    out = tmp_path / "d"
    assert main(["diagnose", "--model", ROBOT, "--train", str(recs / "short.npz"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "held-out part" in err
    assert f"≥ {MIN_BLOCKS * MIN_BLOCK_S:g} s" in err and "--holdout REC" in err
    need = float(re.search(r"record ≥ ([\d.]+) s", err).group(1))
    assert 3.0 < need < 9.0                                        # and the 9 s log below is long enough
    assert not out.exists() or not any(out.rglob("*"))


def test_one_log_holds_out_its_end_and_stderr_holds_no_carriage_return(recs, tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["diagnose", "--model", ROBOT, "--train", str(recs / "long.npz"), "--candidates", "viscous_coulomb",
                 "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "held out: the last 33.3 % (--holdout-fraction 0.333, the default without --holdout)" in cap.out
    assert "long.npz after 6 s" in cap.out
    assert "\r" not in cap.err and "\r" not in cap.out
    assert (out / "report.html").is_file()
    assert main(["diagnose", "--model", ROBOT, "--train", str(recs / "long.npz"), "--candidates", "viscous_coulomb",
                 "--split-at", "5", "--cutoff-hz", "20", "--out", str(tmp_path / "d2")]) == 0
    assert "held out: all after the first 5 s (--split-at) of every --train recording" in capsys.readouterr().out


def test_diagnose_redirected_to_a_file_writes_no_carriage_return(recs, tmp_path):
    """The command as a user runs it, stderr redirected to a file (a progress bar's updates would be one long line)."""
    import subprocess
    import sys

    err = tmp_path / "err.txt"
    with open(err, "wb") as fh:
        done = subprocess.run([sys.executable, "-m", "proprio", "diagnose", "--model", ROBOT, "--train",
                               str(recs / "long.npz"), "--candidates", "viscous_coulomb", "--out", str(tmp_path / "d")],
                              stdout=subprocess.DEVNULL, stderr=fh, timeout=600)
    assert done.returncode == 0, err.read_text()
    assert b"\r" not in err.read_bytes()


def test_train_writes_no_carriage_return_off_a_terminal(recs, tmp_path, capsys):
    assert main(["train", "--config", "train_demo", "--backbone", ROBOT, "--data", str(recs / "long.npz"),
                 "--out", str(tmp_path / "m.pt")]) == 0
    cap = capsys.readouterr()
    assert "\r" not in cap.err + cap.out


def test_estimate_prints_the_statistics_it_announces(recs, tmp_path, capsys):
    assert main(["estimate", "--model", ROBOT, "--recording", str(recs / "long.npz"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    n = int(re.search(r"statistics over the (\d+) valid ones", out).group(1))
    assert n > 0
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith(("jacobian", "momentum"))}
    assert set(rows) == {"jacobian", "momentum"} and "RMS f̂ [fx fy fz] N" in out
    assert all(len(re.findall(r"\d+\.\d\d", row)) == 3 for row in rows.values())


def test_an_unknown_tau_kind_is_named_with_the_valid_values(recs, tmp_path, capsys):
    assert main(["identify", "--robot", ROBOT, "--train", str(recs / "free_text_tau.npz"), "--out",
                 str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "'measured by the sensor' is unknown" in err and "'link_sensor'" in err and "'drive'" in err
    assert "set the description's drive.tau_kind" not in err


def _suggested(err: str) -> str:
    """The flag and value an error suggests ('pass --model X')."""
    m = re.search(r"pass (--\w[\w-]*) (\S+)$", err.strip())
    assert m, err
    return f"{m.group(1)} {m.group(2)}"


OTHER_ARM = {                   # every command that reads a log against a robot: {o} output, {r} the log
    "estimate": "estimate --model {robot} --recording {r} --out {o}/e",
    "inspect": "inspect {r} --robot {robot}",
    "identify": "identify --robot {robot} --train {r} --out {o}/m.npz --method ols",
    "diagnose": "diagnose --model {robot} --train {r} --holdout {r} --candidates viscous_coulomb --out {o}/d",
    "train": "train --config train_demo --backbone {robot} --data {r} --out {o}/m.pt",
}


@pytest.mark.parametrize("command", list(OTHER_ARM))
def test_a_log_of_another_arm_is_refused_and_the_advice_works(command, recs, tmp_path, capsys):
    """The one check (estimate's) in every command; its suggested --model/--robot value, followed, works."""
    log = recs / "other_arm" / "log.npz"
    line = OTHER_ARM[command]
    assert main(shlex.split(line.format(robot=ROBOT, r=log, o=tmp_path))) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "other_arm" in err, err
    flag, value = _suggested(err).split()
    assert value == str(recs / "other_arm")
    fixed = line.format(robot=value, r=log, o=tmp_path / "fixed")
    assert flag in fixed.split()
    assert main(shlex.split(fixed)) == 0, capsys.readouterr().err


def test_replay_and_view_refuse_a_log_of_another_arm(recs, tmp_path, capsys):
    log = recs / "other_arm" / "log.npz"
    for line in (f"simulate --twin iiwa14_nominal_twin --replay {log} --out {tmp_path}/r.npz",
                 f"view {log} --model {ROBOT} --html {tmp_path}/v.html"):
        assert main(line.split()) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "other_arm" in err and "--" in err, err


def test_identify_advises_offsets_and_sdp_and_the_advice_works(recs, tmp_path, capsys):
    """A constant 0.8 N·m on joint 1 (the LWR 4+ joint-1 case): identify says so and suggests --offsets; followed,
    the advice is gone. An OLS model that is not physically consistent is named with --method sdp."""
    base = ["identify", "--robot", ROBOT, "--train", str(recs / "offset.npz"), "--out", str(tmp_path / "m.npz")]
    assert main(base) == 0
    out = capsys.readouterr().out
    advice = [line for line in out.splitlines() if line.startswith("advice:")]
    offsets = [line for line in advice if "--offsets" in line]
    assert len(offsets) == 1 and "joint 1:" in offsets[0] and not re.search(r"joint [2-7]:", offsets[0])
    assert main(base + ["--offsets"]) == 0
    assert "--offsets fits" not in capsys.readouterr().out
    assert any("not physically consistent" in line and "--method sdp" in line for line in advice)
    assert main(base + ["--offsets", "--method", "sdp"]) == 0
    assert "advice:" not in capsys.readouterr().out
    # the same motion without the offset: no constant part is claimed
    assert main(["identify", "--robot", ROBOT, "--train", str(recs / "long.npz"), "--out", str(tmp_path / "n.npz")]) == 0
    assert "--offsets fits" not in capsys.readouterr().out


def test_drakes_inertia_warnings_are_one_line(caplog):
    import logging

    from proprio.cli import INERTIA_WARNING, _OneInertiaWarning

    log = logging.getLogger("drake")
    filt = _OneInertiaWarning()
    log.addFilter(filt)
    try:
        with caplog.at_level(logging.WARNING, logger="drake"):
            for k in range(20):
                log.warning("inertia %d\ndid not pass the test CouldBePhysicallyValid().\nprincipal moments", k)
            log.warning("another warning")
    finally:
        log.removeFilter(filt)
    messages = [r.getMessage() for r in caplog.records]
    assert messages == [INERTIA_WARNING, "another warning"]


LWR = Path(__file__).resolve().parents[2] / "shared" / "data" / "kuka_lwr4"


def test_estimate_of_an_lwr_log_without_model_suggests_a_model_that_works(tmp_path, capsys):
    """Without --model, estimate of an LWR 4+ file suggested `--model kuka_lwr4plus` (not a robot anyone can load);
    now the folder that holds its robot.yaml, and that runs."""
    log = LWR / "measurements_1.npz"
    if not log.exists():
        pytest.skip(f"{LWR} not present")
    assert main(["estimate", "--recording", str(log), "--out", str(tmp_path / "e")]) == 2
    suggestion = _suggested(capsys.readouterr().err)
    assert suggestion == f"--model {LWR}"
    assert main(["estimate", "--recording", str(log), "--out", str(tmp_path / "e"), *suggestion.split()]) == 0


ADVICE = [   # (command that fails, the advice's flags or command line in its message, the command followed)
    ("train-grid --data {d}/long.npz --out {o}/g --search 2", "add --backend ray",
     "train-grid --data {d}/long.npz --out {o}/g --search 2 --backend ray"),
    ("diagnose --model iiwa14_nominal --train {d}/short.npz --candidates viscous_coulomb --out {o}/d",
     "--holdout REC", "diagnose --model iiwa14_nominal --train {d}/short.npz --candidates viscous_coulomb --out {o}/d "
     "--holdout {d}/long.npz"),
    ("inspect {o}/semicolon.csv", "`proprio import MAPPING.yaml --out REC.npz`",
     "import proprio/configs/import_tx40.yaml --out {o}/r.npz"),
]


@pytest.mark.parametrize("failing,said,followed", ADVICE, ids=[a[1] for a in ADVICE])
def test_the_advice_of_an_error_works_when_followed(failing, said, followed, recs, tmp_path, capsys, monkeypatch):
    """Each error that suggests a flag or a command: the suggestion is in its message, and the command line with it
    parses (and, where it runs in seconds here, runs: the diagnosis)."""
    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    (tmp_path / "semicolon.csv").write_text("t;q1\n0;1\n")
    fill = lambda s: s.format(d=recs, o=tmp_path)  # noqa: E731
    assert main(shlex.split(fill(failing))) == 2
    assert said in capsys.readouterr().err
    args = build_parser().parse_args(shlex.split(fill(followed)))       # the advice parses ...
    assert args.func
    if followed.startswith("diagnose"):                                  # ... and runs
        assert main(shlex.split(fill(followed))) == 0
