"""``proprio import``: robot log files (CSV/TXT, any layout) → a Recording, driven by a mapping YAML."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from proprio.cli import main
from proprio.description import DescriptionError
from proprio.importer import LogImportError, import_recording, load_mapping, read_table
from proprio.recording import Recording, load_recording, save_recording

REPO = Path(__file__).resolve().parents[1]
TX40_DIR = Path(os.environ.get("PROPRIO_SHARED", REPO.parent / "shared")) / "data" / "staubli_tx40"
TX40_MAPPING = REPO / "proprio" / "configs" / "import_tx40.yaml"
RNG = np.random.default_rng(3)
Q = RNG.uniform(-1.0, 1.0, (50, 3))                  # joint-side truth [rad]
TAU = RNG.uniform(-20.0, 20.0, (50, 3))              # joint-side truth [N·m]
R = np.array([[10.0, 0.0, 0.0], [0.0, -20.0, 0.0], [0.0, 5.0, 5.0]])   # q_motor = R q (motor 3 couples joint 2)


def write_mapping(tmp_path: Path, body: dict) -> Path:
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump({"format": "proprio-import/v1", "joints": 3, **body}))
    return path


def test_headerless_semicolon_decimal_comma_table(tmp_path):
    t_ms = np.arange(50) * 2.0 + 100.0
    rows = np.column_stack([t_ms, np.degrees(Q), TAU])
    (tmp_path / "log.txt").write_text("\n".join(";".join(f"{v:.10f}".replace(".", ",") for v in r) for r in rows))
    path = write_mapping(tmp_path, {"file": "log.txt", "time": {"column": 0, "unit": "ms"},
                                    "q": {"columns": [1, 2, 3], "unit": "deg"}, "tau": {"columns": [4, 5, 6]}})
    rec = import_recording(path)
    np.testing.assert_allclose(rec.t, (t_ms - 100.0) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(rec.q, Q, atol=1e-9)
    np.testing.assert_allclose(rec.tau, TAU, atol=1e-9)
    assert rec.meta["tau_kind"] == "link_sensor" and rec.meta["rate_hz"] == pytest.approx(500.0)


def test_one_file_per_channel_motor_side_counts_current_and_coupling(tmp_path):
    cpr, kt = 4096.0, np.array([0.5, 0.2, 0.1])
    q_motor_counts = (Q @ R.T) * cpr / (2 * math.pi)
    # τ = Rᵀ τ_motor ⇒ τ_motor = R⁻ᵀ τ, and the current is τ_motor / k_t
    current = np.linalg.solve(R.T, TAU.T).T / kt
    np.savetxt(tmp_path / "enc.csv", q_motor_counts, delimiter=",", header="m1,m2,m3", comments="")
    np.savetxt(tmp_path / "cur.tsv", current, delimiter="\t")
    offset = [0.1, -0.2, 0.0]
    path = write_mapping(tmp_path, {
        "rate_hz": 1000, "q": {"file": "enc.csv", "columns": ["m1", "m2", "m3"], "unit": "counts",
                               "counts_per_rev": cpr, "side": "motor"},
        "tau": {"file": "cur.tsv", "quantity": "motor_current"}, "q_offset": offset, "tau_kind": "drive",
        "drive": {"gear_ratio": [10.0, -20.0, 5.0], "coupling": [{"motor": 3, "joint": 2, "ratio": 5.0}],
                  "torque_constant": kt.tolist()}})
    rec = import_recording(path)
    np.testing.assert_allclose(rec.q, Q + offset, atol=1e-9)
    np.testing.assert_allclose(rec.tau, TAU, atol=1e-9)
    np.testing.assert_allclose(np.diff(rec.t), 1e-3)
    assert rec.meta["tau_kind"] == "drive" and np.allclose(rec.meta["import"]["motor_matrix"], R)


@pytest.mark.parametrize("text, names", [("a b c\n1 2 3\n4 5 6\n", ["a", "b", "c"]), ("1|2|3\n4|5|6\n", None),
                                         ('"x","y","z"\n1.5,2,3\n4,5,6\n', ["x", "y", "z"])])
def test_read_table_sniffs_layout(tmp_path, text, names):
    (tmp_path / "t.txt").write_text(text)
    header, data = read_table(tmp_path / "t.txt")
    assert header == names and data.shape == (2, 3) and data[1, 2] == 6.0


@pytest.mark.parametrize("body, field", [
    ({"rate_hz": 10, "q": {"file": "x.csv", "colums": [0, 1, 2]}, "tau": {"file": "x.csv"}}, "did you mean 'columns'"),
    ({"rate_hz": 10, "q": {"file": "x.csv"}, "tau": {"file": "x.csv"}, "drvie": {}}, "did you mean 'drive'"),
    ({"q": {"file": "x.csv"}, "tau": {"file": "x.csv"}}, "rate_hz"),
    ({"rate_hz": 10, "q": {"file": "x.csv"}, "tau": {"file": "x.csv"}, "tau_kind": "motor"}, "tau_kind"),
    ({"rate_hz": 10, "q": {"file": "x.csv"}, "tau": {"file": "x.csv"}, "drive": {"gear_ratio": [1, 0, 1]}},
     "gear_ratio"),
])
def test_bad_mapping_names_the_field(tmp_path, body, field):
    with pytest.raises((LogImportError, DescriptionError), match=field):
        load_mapping(write_mapping(tmp_path, body))


def test_text_cell_and_missing_column_are_named(tmp_path):
    (tmp_path / "x.csv").write_text("q1,q2,q3,t1,t2,t3\n1,2,3,4,5,6\n1,2,oops,4,5,6\n")
    path = write_mapping(tmp_path, {"rate_hz": 10, "file": "x.csv", "q": {"columns": ["q1", "q2", "q3"]},
                                    "tau": {"columns": ["t1", "t2", "tau3"]}})
    with pytest.raises(LogImportError, match="x.csv.*oops"):
        import_recording(path)
    (tmp_path / "x.csv").write_text("q1,q2,q3,t1,t2,t3\n1,2,3,4,5,6\n1,2,3,4,5,6\n")
    with pytest.raises(LogImportError, match="tau: column 'tau3' not in x.csv"):
        import_recording(path)


def test_stages_given_a_csv_point_to_import(tmp_path, capsys):
    (tmp_path / "log.csv").write_text("1,2\n3,4\n")
    assert main(["identify", "--robot", "iiwa14_nominal", "--train", str(tmp_path / "log.csv"),
                 "--out", str(tmp_path / "m.npz")]) == 2
    assert "proprio import" in capsys.readouterr().err
    assert main(["inspect", str(tmp_path / "log.csv")]) == 2
    assert "proprio import" in capsys.readouterr().err
    assert main(["diagnose", "--model", "iiwa14_nominal", "--train", str(tmp_path / "log.csv"),
                 "--out", str(tmp_path / "d")]) == 2
    assert "proprio import" in capsys.readouterr().err


def test_estimate_on_another_robots_recording_says_what_to_pass(tmp_path, capsys):
    t = np.arange(200) * 0.005
    rec = Recording(t=t, q=np.zeros((200, 7)) + 0.1 * np.sin(t)[:, None], tau=np.zeros((200, 7)),
                    meta={"robot": "ur_like_arm"})
    save_recording(rec, tmp_path / "other.npz")
    assert main(["estimate", "--model", "iiwa14_identified", "--recording", str(tmp_path / "other.npz"),
                 "--out", str(tmp_path / "est")]) == 2
    err = capsys.readouterr().err
    assert "pass --model with the description of 'ur_like_arm'" in err
    assert not (tmp_path / "est").exists()


def test_tx40_logs_import(tmp_path, capsys):
    if not (TX40_DIR / "curr_data.csv").exists():
        pytest.skip(f"TX40 data not found at {TX40_DIR}")
    out = tmp_path / "tx40.npz"
    assert main(["import", str(TX40_MAPPING), "--data-dir", str(TX40_DIR), "--out", str(out),
                 "--robot", str(TX40_DIR / "tx40_mdh_modified.urdf")]) == 0
    rec = load_recording(out)
    assert rec.n_samples == 45000 and rec.rate_hz == pytest.approx(5000.0) and rec.meta["tau_kind"] == "drive"
    # at rest at the end: encoder zero mapped onto the URDF zero (q2 − π/2, q3 + π/2)
    np.testing.assert_allclose(rec.q[-1], 0.0, atol=1e-3)
    # ranges: every joint moves (≥ 0.5 rad) inside ±4.71 rad; drive torques up to ≈95 N·m on joints 1–2 (README)
    span = rec.q.max(axis=0) - rec.q.min(axis=0)
    assert np.all(span > 0.5) and np.all(np.abs(rec.q) < 4.72)
    peak = np.abs(rec.tau).max(axis=0)
    assert 85.0 < peak[0] < 100.0 and 85.0 < peak[1] < 100.0 and np.all(peak[2:] < 40.0)
    # held still, the shoulder carries the arm: joint 2's drive torque has gravity's sign and size (model: −23.6 N·m)
    assert -30.0 < rec.tau[-2000:, 1].mean() < -20.0
    # joint 6 is driven by motor 6 alone: τ6 = N6 τ_motor6
    raw = np.loadtxt(TX40_DIR / "curr_data.csv", delimiter=",", skiprows=1, max_rows=2000)
    np.testing.assert_allclose(rec.tau[:2000, 5], 32.0 * raw[:, 5], rtol=1e-12)
    np.testing.assert_allclose(rec.tau[:2000, 4], 45.0 * raw[:, 4] + 32.0 * raw[:, 5], rtol=1e-12)
