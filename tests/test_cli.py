"""The command line as users call it: JSON keys, files, and exit code 2 on bad input."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trainclimate.cli import main
from trainclimate.data.trajectory import read_trajectories
from trainclimate.sim.params import CoachParams


def call(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def call_json(capsys, *argv):
    code, out, err = call(capsys, *argv, "--json")
    assert code == 0, err
    return json.loads(out)


def test_scenarios_lists_the_contract_names(capsys):
    data = call_json(capsys, "scenarios")
    names = {s["name"] for s in data["scenarios"]}
    assert {"winter-day", "parked-heating-nov", "parked-cooling-oct"} <= names
    assert all(s["description"] for s in data["scenarios"])


def test_simulate_prints_the_contract_keys(capsys):
    data = call_json(capsys, "simulate", "--scenario", "parked-heating-nov", "--hours", "1")
    for key in (
        "energy_kwh",
        "avg_hourly_violation_k",
        "discomfort_kh",
        "mean_power_kw",
        "hours",
        "controller",
        "scenario",
    ):
        assert key in data
    assert data["hours"] == pytest.approx(1.0)
    assert data["controller"] == "rule" and data["scenario"] == "parked-heating-nov"
    # a cold November hour: heating, several kW
    assert 3.0 < data["mean_power_kw"] < 30.0
    assert data["energy_kwh"] == pytest.approx(data["mean_power_kw"] * 1.0, rel=1e-9)


def test_simulate_writes_the_full_time_series(capsys, tmp_path):
    out = tmp_path / "run.parquet"
    data = call_json(
        capsys,
        "simulate",
        "--scenario",
        "parked-cooling-oct",
        "--hours",
        "0.5",
        "--coaches",
        "2",
        "--out",
        str(out),
    )
    frame = pd.read_parquet(out)
    assert set(frame["coach"]) == {0, 1}
    assert len(frame) == 2 * 180
    for col in (
        "t_room_up_c",
        "t_ref_c",
        "t_rule_c",
        "power_kw",
        "hvac_state",
        "fresh_air_fraction",
        "q_solar_roof_w",
        "q_ventilation_low_w",
    ):
        assert col in frame.columns
    coach0 = frame[frame["coach"] == 0]
    assert coach0["power_kw"].sum() * 10 / 3600 == pytest.approx(data["coaches"][0]["energy_kwh"])


def test_coach_params_round_trip(capsys, tmp_path):
    data = call_json(capsys, "coach-params", "--default")
    assert data == CoachParams().to_dict()
    data["window_g"] = 0.2
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    run = call_json(
        capsys,
        "simulate",
        "--scenario",
        "parked-cooling-oct",
        "--hours",
        "0.5",
        "--coach-params",
        str(path),
    )
    assert run["energy_kwh"] > 0


def write_weather(path, rows):
    pd.DataFrame(rows, columns=["time", "t_amb_c", "ghi_w_m2"]).to_csv(path, index=False)


def test_weather_csv_drives_the_run(capsys, tmp_path):
    path = tmp_path / "w.csv"
    times = pd.date_range("2023-07-10 10:00", periods=13, freq="15min", tz="Europe/Zurich")
    write_weather(path, [(t.isoformat(), 30.0 + i * 0.2, 700.0) for i, t in enumerate(times)])
    data = call_json(
        capsys, "simulate", "--scenario", "parked-cooling-oct", "--weather-csv", str(path)
    )
    assert data["hours"] == pytest.approx(3.0)
    cooler = call_json(capsys, "simulate", "--scenario", "parked-cooling-oct", "--hours", "3")
    assert data["energy_kwh"] != cooler["energy_kwh"]


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["simulate", "--scenario", "nope"], "unknown scenario 'nope'"),
        (
            [
                "simulate",
                "--scenario",
                "winter-day",
                "--controller",
                "ddpc",
                "--predictor",
                "no.npz",
            ],
            "model file not found",
        ),
        (["simulate", "--scenario", "winter-day", "--hours", "-1"], "--hours must be positive"),
        (["simulate", "--scenario", "winter-day", "--hours", "0.001"], "shorter than two"),
        (["simulate", "--scenario", "winter-day", "--coaches", "0"], "--coaches"),
        (["simulate"], "--scenario"),
        (["coach-params"], "--default"),
        (["bench", "nothing"], "invalid choice"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(capsys, argv, needle):
    code, out, err = call(capsys, *argv)
    assert code == 2
    assert out == ""
    assert len(err.strip().splitlines()) == 1 and needle in err


@pytest.mark.parametrize(
    ("rows", "needle"),
    [
        ([("2023-07-10T10:00:00+02:00", 20.0)], "ghi_w_m2"),
        ([("yesterday", 20.0, 100.0), ("2023-07-10T11:00:00+02:00", 21.0, 100.0)], "time"),
        (
            [("2023-07-10T11:00:00+02:00", 20.0, 100.0), ("2023-07-10T10:00:00+02:00", 21.0, 1.0)],
            "monoton",
        ),
        (
            [
                ("2023-07-10T10:00:00+02:00", float("nan"), 100.0),
                ("2023-07-10T11:00:00+02:00", 21.0, 100.0),
            ],
            "NaN",
        ),
    ],
)
def test_malformed_weather_csv_exits_2(capsys, tmp_path, rows, needle):
    path = tmp_path / "bad.csv"
    cols = ["time", "t_amb_c", "ghi_w_m2"][: len(rows[0])]
    pd.DataFrame(rows, columns=cols).to_csv(path, index=False)
    code, out, err = call(
        capsys, "simulate", "--scenario", "winter-day", "--weather-csv", str(path)
    )
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1
    assert needle.lower() in err.lower()


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"c_room_j_k": [-9e4, 6e4, 1e5]}, "c_room_j_k"),
        ({"distribution": (np.eye(6) * 0.5).tolist()}, "column 0 sums to 0.5000"),
        ({"warp_drive": 1}, "unknown coach parameter 'warp_drive'"),
    ],
)
def test_bad_parameter_file_exits_2(capsys, tmp_path, change, needle):
    path = tmp_path / "p.json"
    path.write_text(json.dumps(change))
    code, _out, err = call(
        capsys, "simulate", "--scenario", "winter-day", "--coach-params", str(path)
    )
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1


def test_bench_simulator_keys(capsys):
    data = call_json(
        capsys, "bench", "simulator", "--coaches", "4", "--days", "0.02", "--loop-coaches", "2"
    )
    assert data["coaches"] == 4 and data["days"] == 0.02
    assert data["coach_days_per_s"] > 0 and data["speedup_vs_loop"] > 0


def test_console_script_is_installed_and_answers():
    exe = shutil.which("trainclimate", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("console script not installed (run through `make test`)")
    done = subprocess.run(
        [exe, "scenarios", "--json"], capture_output=True, text=True, timeout=60, check=True
    )
    assert "winter-day" in {s["name"] for s in json.loads(done.stdout)["scenarios"]}
    bad = subprocess.run(
        [exe, "simulate", "--scenario", "nope"], capture_output=True, text=True, timeout=60
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1


def test_dataset_build_prints_the_contract_keys_and_rebuilds_the_same_from_raw(capsys, tmp_path):
    # two coaches: on the first day coach 124B stands in the depot, 44B is in service
    out = tmp_path / "fleet"
    data = call_json(
        capsys, "dataset", "build", "--out", str(out), "--days", "1", "--coaches", "2",
        "--campaign", "summer",
    )  # fmt: skip
    assert [(r["campaign"], r["sampling_min"]) for r in data["table"]] == [
        ("summer", 1),
        ("summer", 5),
        ("summer", 10),
    ]
    for row in data["table"]:
        found = read_trajectories(out / f"trajectories_{row['sampling_min']}min.parquet")
        assert row["trajectories"] == len(found) >= 1
        assert row["mean_points"] == round(sum(map(len, found)) / len(found), 1)
        assert {(t.campaign, t.coach, t.sampling_min) for t in found} == {
            ("summer", "44B", row["sampling_min"])
        }
    for key in ("dropped_rows", "repaired_rows"):
        assert all(isinstance(v, int) and v >= 0 for v in data[key].values())
    # a summer day at 2 s carries every per-row defect
    assert {"duplicate", "missing_value", "out_of_range", "spike"} <= set(data["dropped_rows"])
    assert data["generated"] == {"files": 6, "rows": data["raw_rows"], "coach_days": 2}
    assert data["unreadable_files"] == [] and data["raw"] == str(out / "raw")
    assert json.loads((out / "dataset.json").read_text())["table"] == data["table"]

    again = call_json(
        capsys, "dataset", "build", "--raw", str(out / "raw"), "--out", str(tmp_path / "again")
    )
    assert "generated" not in again
    for key in ("table", "dropped_rows", "repaired_rows", "raw_rows", "coach_days"):
        assert again[key] == data[key]
    for step in (1, 5, 10):
        name = f"trajectories_{step}min.parquet"
        assert (tmp_path / "again" / name).read_bytes() == (out / name).read_bytes()


def unusable_raw(tmp_path, kind):
    raw = tmp_path / "raw"
    if kind == "missing":
        return raw
    raw.mkdir()
    if kind == "garbage":
        log = raw / "summer" / "hvac" / "124_124B_2023-07-04.csv"
        log.parent.mkdir(parents=True)
        log.write_bytes(bytes(range(256)) * 2)
        (raw / "summer" / "trips" / "124_124B_2023-07-04.csv").parent.mkdir(parents=True)
        (raw / "summer" / "trips" / "124_124B_2023-07-04.csv").write_text("Zug;Abfahrt\n")
        (raw / "notes.csv").write_text("not a fleet log\n")
    return raw


@pytest.mark.parametrize(
    ("kind", "needle"),
    [
        ("missing", "--raw: no such directory"),
        ("empty", "no raw log files under"),
        ("garbage", "no usable trajectory"),
    ],
)
def test_dataset_build_on_missing_empty_or_unusable_raw_exits_2(
    capsys, caplog, tmp_path, kind, needle
):
    raw = unusable_raw(tmp_path, kind)
    code, out, err = call(
        capsys, "dataset", "build", "--raw", str(raw), "--out", str(tmp_path / "o")
    )
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    errors = [line for line in lines if line.startswith("trainclimate: error:")]
    assert len(errors) == 1 and lines[-1] == errors[0] and needle in errors[0]
    assert all(line.startswith("trainclimate: warning:") for line in lines[:-1])
    if kind == "garbage":
        warned = caplog.text + err
        for name in ("hvac/124_124B_2023-07-04.csv", "trips/124_124B_2023-07-04.csv"):
            assert f"unreadable raw file {raw / 'summer' / name}" in warned


def test_dataset_build_rejects_zero_days(capsys, tmp_path):
    code, out, err = call(capsys, "dataset", "build", "--out", str(tmp_path), "--days", "0")
    assert code == 2 and out == "" and "--days and --coaches must be at least 1" in err
