"""The simulator's commands as users call them: JSON keys, files, and exit code 2 on bad input."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helpers.cli import SIMULATE_KEYS, call, call_json
from trainclimate.sim.params import CoachParams


def test_scenarios_lists_the_contract_names(capsys):
    data = call_json(capsys, "scenarios")
    names = {s["name"] for s in data["scenarios"]}
    assert {"winter-day", "parked-heating-nov", "parked-cooling-oct"} <= names
    assert all(s["description"] for s in data["scenarios"])


def test_simulate_prints_the_contract_keys(capsys):
    data = call_json(capsys, "simulate", "--scenario", "parked-heating-nov", "--hours", "1")
    for key in SIMULATE_KEYS:
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
    argv = ["simulate", "--scenario", "parked-cooling-oct", "--hours", "0.5"]
    run = call_json(capsys, *argv, "--coach-params", str(path))
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


@pytest.mark.slow  # two processes of the installed command: ≈ 15 s
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
