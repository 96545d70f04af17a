"""``trainclimate predictor evaluate|fit`` as users call it, on the small fleet dataset: the
contract's JSON keys and shapes, a loadable model file, exit code 2 on bad input. Every call
passes ``--data`` (without it the 2.5-min default dataset would be built)."""

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from trainclimate.cli import main
from trainclimate.data.trajectory import Trajectory, TrajectoryWriter
from trainclimate.predict import ARXPredictor, TransientPredictor
from trainclimate.predict.artifact import load_predictor
from trainclimate.predict.evaluate import load_split, mae_per_step

SETTING = ("--method", "transient", "--sampling-min", "5", "--rho", "6", "--horizon", "6")


def call(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def fails_with(capsys, *argv):
    code, out, err = call(capsys, *argv)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("trainclimate: error: ")
    return lines[0]


def test_evaluate_prints_the_contract_keys(capsys, small_dataset):
    code, out, err = call(
        capsys, "predictor", "evaluate", "--data", str(small_dataset), *SETTING, "--json"
    )
    assert code == 0, err
    data = json.loads(out)
    assert len(data["mae_per_step_c"]) == 6
    assert np.shape(data["mae_per_step_deck_c"]) == (6, 3)
    # the numbers are those of the Python API on the same split
    train, val = load_split(small_dataset, 5)
    mae = mae_per_step(TransientPredictor(6, 6).fit(train), val)
    np.testing.assert_allclose(data["mae_per_step_deck_c"], mae, rtol=1e-12)
    np.testing.assert_allclose(data["mae_per_step_c"], mae.mean(axis=1), rtol=1e-12)
    assert max(data["mae_per_step_c"]) < 0.25
    assert data["validation_coaches"] == ["66A", "66B"]
    assert (data["method"], data["sampling_min"], data["rho"], data["horizon"]) == (
        "transient",
        5,
        6,
        6,
    )


def test_evaluate_prints_a_summary_without_json(capsys, small_dataset):
    code, out, _ = call(capsys, "predictor", "evaluate", "--data", str(small_dataset), *SETTING)
    assert code == 0
    assert out.startswith("transient predictor, 5 min, ρ = 6, T = 6: MAE per step")
    assert "66A, 66B" in out


def test_fit_writes_a_loadable_model(capsys, small_dataset, tmp_path):
    path = tmp_path / "models" / "tp.npz"
    code, out, err = call(
        capsys,
        "predictor",
        "fit",
        "--data",
        str(small_dataset),
        "--method",
        "arx",
        "--sampling-min",
        "10",
        "--rho",
        "3",
        "--horizon",
        "2",
        "--out",
        str(path),
        "--json",
    )
    assert code == 0, err
    data = json.loads(out)
    assert data["out"] == str(path)
    model = load_predictor(path)
    assert (model.method, model.rho, model.horizon, model.sampling_min) == ("arx", 3, 2, 10)
    assert model.metadata["validation"]["mae_per_step_c"] == data["mae_per_step_c"]
    assert model.data_hash == data["data_hash"]
    train, _ = load_split(small_dataset, 10)
    np.testing.assert_allclose(model.H, ARXPredictor(3, 2).fit(train).H, rtol=1e-12)


def test_data_of_an_empty_directory_is_a_usage_error(capsys, tmp_path):
    line = fails_with(capsys, "predictor", "evaluate", "--data", str(tmp_path), *SETTING)
    assert "holds no dataset" in line
    line = fails_with(capsys, "predictor", "fit", "--data", str(tmp_path / "nope"), "--out", "x")
    assert "holds no dataset" in line


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--rho", "0", "--rho and --horizon must be at least 1"),
        ("--horizon", "-2", "--rho and --horizon must be at least 1"),
        ("--sampling-min", "2", "--sampling-min must be 1, 5 or 10"),
        ("--method", "kalman", "invalid choice: 'kalman'"),
        ("--rho", "six", "invalid int value: 'six'"),
    ],
)
def test_bad_settings_exit_2(capsys, small_dataset, option, value, message):
    line = fails_with(
        capsys, "predictor", "evaluate", "--data", str(small_dataset), option, value, "--json"
    )
    assert message in line


def test_too_little_data_exits_2_with_the_predictor_data_error(capsys, small_dataset):
    # 10-min trajectories of at most 74 samples: few windows of 60
    line = fails_with(
        capsys,
        "predictor",
        "evaluate",
        "--data",
        str(small_dataset),
        "--sampling-min",
        "10",
        "--rho",
        "30",
        "--horizon",
        "30",
        "--json",
    )
    assert line.startswith(
        "trainclimate: error: too little data for transient with ρ = 30, T = 30: "
        "the fit needs at least 540 windows of 60 consecutive samples"
    )
    assert "; got 29 from 2 of 27 trajectories (798 samples)" in line


def test_no_validation_window_exits_2(capsys, tmp_path):
    # coaches A, B, C train; D (held out) has only trajectories shorter than ρ + T
    rng = np.random.default_rng(0)
    with TrajectoryWriter(tmp_path / "trajectories_5min.parquet") as writer:
        for coach, n in (("A", 200), ("B", 200), ("C", 200), ("D", 5)):
            z = rng.standard_normal((n, 9)) * [1, 1, 1, 1, 1, 100, 100, 10, 10]
            time = pd.date_range("2022-03-01", periods=n, freq="5min", tz="UTC")
            writer.write([Trajectory(time, z[:, :3], z[:, 3:4], z[:, 4:], "c", "1", coach, 5)])
    line = fails_with(capsys, "predictor", "evaluate", "--data", str(tmp_path), *SETTING)
    assert "no validation trajectory has the 12 samples of one window" in line


def test_a_missing_sampling_time_exits_2(capsys, small_dataset, tmp_path):
    shutil.copy(small_dataset / "trajectories_5min.parquet", tmp_path)
    line = fails_with(
        capsys, "predictor", "evaluate", "--data", str(tmp_path), "--sampling-min", "10"
    )
    assert "no 10-min trajectories" in line
