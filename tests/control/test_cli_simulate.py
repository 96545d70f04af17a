"""`trainclimate simulate` with the DDPC layer and the band-edge reference (in-process, like
tests/test_cli.py; always with --predictor: the default model would build the default dataset)."""

from __future__ import annotations

import json

import pytest

from helpers.cli import SIMULATE_KEYS
from trainclimate.cli import main


def call(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def simulate(capsys, *argv):
    code, out, err = call(capsys, "simulate", "--scenario", "parked-heating-nov", *argv, "--json")
    assert code == 0, err
    return json.loads(out)


def test_ddpc_with_a_model_file(capsys, small_predictor_file):
    data = simulate(
        capsys, "--hours", "2", "--controller", "ddpc", "--predictor", str(small_predictor_file)
    )
    for key in SIMULATE_KEYS:
        assert key in data
    assert data["controller"] == "ddpc" and data["scenario"] == "parked-heating-nov"
    assert data["hours"] == pytest.approx(2.0)
    ticks = data["controller_ticks"]
    # 24 ticks of 5 min, the first at t = 5 min: 11 of lead-in, then the DDPC optimum
    assert ticks["ticks"] == 23
    assert ticks["reasons"] == {"ok": 12, "warmup": 11}
    assert 0 < ticks["median_solve_ms"] < 50 and ticks["median_step_ms"] >= ticks["median_solve_ms"]
    rule = simulate(capsys, "--hours", "2")
    assert "controller_ticks" not in rule
    assert data["energy_kwh"] < rule["energy_kwh"]


def test_edge_needs_no_model(capsys):
    data = simulate(capsys, "--hours", "1.5", "--controller", "edge")
    assert data["controller"] == "edge"
    assert data["controller_ticks"]["reasons"] == {"ok": 6, "warmup": 11}
    assert data["controller_ticks"]["median_solve_ms"] is None  # no optimisation


@pytest.mark.parametrize("forecast", ["persistence", "noisy"])
def test_other_forecasts_run(capsys, small_predictor_file, forecast):
    data = simulate(
        capsys, "--hours", "1.5", "--controller", "ddpc", "--predictor", str(small_predictor_file),
        "--forecast", forecast,
    )  # fmt: skip
    assert data["controller_ticks"]["reasons"] == {"ok": 6, "warmup": 11}
    assert data["avg_hourly_violation_k"] < 0.2


def test_human_summary(capsys, small_predictor_file):
    code, out, _ = call(
        capsys, "simulate", "--scenario", "parked-heating-nov", "--hours", "1",
        "--controller", "ddpc", "--predictor", str(small_predictor_file),
    )  # fmt: skip
    assert code == 0
    assert out.startswith("parked-heating-nov (ddpc, 1 coach(es), 1.0 h)")


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--predictor", "missing.npz"], "model file not found: missing.npz"),
        (["--forecast", "oracle"], "invalid choice: 'oracle'"),
    ],
)
def test_bad_model_or_forecast_exits_2(capsys, tmp_path, argv, needle):
    code, out, err = call(
        capsys, "simulate", "--scenario", "parked-heating-nov", "--hours", "1",
        "--controller", "ddpc", *argv, "--json",
    )  # fmt: skip
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("trainclimate: error: ")
    assert needle in err


def test_corrupt_model_file_exits_2(capsys, tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a model")
    code, _, err = call(
        capsys, "simulate", "--scenario", "parked-heating-nov", "--hours", "1",
        "--controller", "ddpc", "--predictor", str(bad), "--json",
    )  # fmt: skip
    assert code == 2 and err.count("\n") == 1 and "is not a trainclimate model file" in err
