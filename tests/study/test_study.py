"""Fleet studies on Dask: the same numbers on a LocalCluster and on a scheduler with two workers
started by hand, resumed without recomputing, a failing chunk named, the situations counted.

The study is small (4 coaches × 2 winter days, chunks of 2 coaches × 1 day, rule + DDPC with the
tests' small predictor): ≈ 5 s per chunk.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers.cli import call
from helpers.processes import free_port
from trainclimate.cli import main
from trainclimate.sim.params import CoachParams
from trainclimate.study import runner
from trainclimate.study.chunk import SITUATIONS, run_chunk
from trainclimate.study.plan import StudySpec, study_weather
from trainclimate.study.runner import ChunkError, read_chunks, run_study
from trainclimate.study.summary import summarise

DASK = Path(sys.executable).with_name("dask")


def study_argv(predictor_file, out, *extra) -> list[str]:
    return [
        "study", "fleet", "--coaches", "4", "--start", "2025-01-14", "--days", "2",
        "--chunk-coaches", "2", "--chunk-days", "1", "--parked-share", "0.5",
        "--predictor", str(predictor_file), "--out", str(out), "--json", *extra,
    ]  # fmt: skip


def run_cli(capsys, argv) -> dict:
    code, out, err = call(capsys, *argv)
    assert code == 0, err
    return json.loads(out)


@pytest.fixture(scope="module")
def local(small_predictor_file, tmp_path_factory):
    """The study on the default LocalCluster (2 workers), with its HTML report."""
    out = tmp_path_factory.mktemp("local")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(study_argv(small_predictor_file, out, "--workers", "2", "--html"))
    assert code == 0
    return out, json.loads(buf.getvalue())


def test_a_study_gives_totals_per_month_situation_and_coach(local):
    out, d = local
    assert (d["coach_days"], d["chunks"], d["chunks_skipped"], d["chunks_run"]) == (8, 4, 0, 4)
    assert d["meter"] == "hvac"
    # a winter fortnight's layer saves on the HVAC units, at a small comfort cost
    assert 1.0 < d["savings_pct"] < 20.0
    assert d["energy_ddpc_kwh"] < d["energy_rule_kwh"]
    assert d["avg_hourly_violation_k"] < 0.25
    assert d["savings_by_meter_pct"]["hvac_and_floor"] < d["savings_pct"]
    for key in ("energy_rule_kwh", "energy_ddpc_kwh"):
        for rows in (d["by_month"], d["by_situation"], d["by_coach"]):
            assert math.isclose(sum(r[key] for r in rows), d[key], rel_tol=1e-9)
    assert {r["situation"] for r in d["by_situation"]} <= set(SITUATIONS)
    assert "in service" in {r["situation"] for r in d["by_situation"]}
    assert math.isclose(d["saved_chf"], (d["energy_rule_kwh"] - d["energy_ddpc_kwh"]) * 0.20)
    assert math.isclose(d["saved_t_co2"], d["saved_mwh"] * 0.125)
    assert len(d["by_coach"]) == 4 and d["coach_savings_pct"]["min"] <= d["savings_pct"]
    assert sorted(p.name for p in (out / "chunks").iterdir()) == [
        "c00000-00001_d000-000.parquet",
        "c00000-00001_d001-001.parquet",
        "c00002-00003_d000-000.parquet",
        "c00002-00003_d001-001.parquet",
    ]
    html = Path(d["html"]).read_text()
    assert html.count("plotly-graph-div") == 4 and "Comfort cost" in html


def test_the_savings_carry_a_bootstrap_interval_and_the_forecast(local):
    _, d = local
    assert d["study"]["forecast"] == "persistence"  # what the service's controller gets
    for row in (d, *d["by_month"]):
        low, high = row["savings_ci95_pct"]
        assert low < row["savings_pct"] < high and row["savings_ci95_reason"] is None
    assert d["bootstrap"]["resamples"] == 9999 and d["bootstrap"]["confidence"] == 0.95
    assert {"savings_ci95_pct", "savings_ci95_reason"} <= set(d["by_situation"][0])
    assert "95 % CI" in Path(d["html"]).read_text()


def test_one_coach_gives_no_interval_and_says_why(local):
    out, d = local
    spec = StudySpec(
        coach_ids=tuple(f"S{i + 1:04d}" for i in range(4)),
        coach_params=(CoachParams().to_dict(),) * 4,
        start="2025-01-14",
        days=2,
        chunk_coaches=2,
        chunk_days=1,
    )  # study_argv's chunks
    frame = read_chunks(spec, out)
    one = summarise(frame[frame["coach_index"] == 0], spec)
    assert one["savings_pct"] is not None and one["savings_ci95_pct"] is None
    assert "at least 2 coaches and 2 days (1 × 2 here)" in one["savings_ci95_reason"]
    assert summarise(frame, spec)["savings_ci95_pct"] == d["savings_ci95_pct"]


def test_the_text_gives_the_saving_with_its_interval(local, small_predictor_file, capsys):
    out, d = local
    code, text, err = call(capsys, *study_argv(small_predictor_file, out)[:-1])
    assert code == 0, err
    low, high = d["savings_ci95_pct"]
    assert f"savings {d['savings_pct']:.1f} % (95 % CI {low:.1f} to {high:.1f})" in text
    assert "persistence forecast" in text


def test_a_rerun_skips_every_chunk_with_the_same_totals(local, small_predictor_file, capsys):
    out, first = local
    again = run_cli(capsys, study_argv(small_predictor_file, out))
    assert (again["chunks_skipped"], again["chunks_run"], again["workers"]) == (4, 0, 0)
    for key in ("coach_days", "energy_rule_kwh", "energy_ddpc_kwh", "savings_pct"):
        assert again[key] == first[key]
    assert again["savings_ci95_pct"] == first["savings_ci95_pct"]  # the bootstrap is seeded


def test_a_lost_chunk_alone_is_recomputed(local, small_predictor_file, capsys, tmp_path):
    out, first = local
    copy = tmp_path / "study"
    copy.mkdir()
    (copy / "study.json").write_text((out / "study.json").read_text())
    (copy / "chunks").mkdir()
    for p in sorted((out / "chunks").iterdir())[1:]:  # as if killed with one chunk in flight
        (copy / "chunks" / p.name).write_bytes(p.read_bytes())
    again = run_cli(capsys, study_argv(small_predictor_file, copy, "--workers", "1"))
    assert (again["chunks_skipped"], again["chunks_run"]) == (3, 1)
    assert again["energy_ddpc_kwh"] == first["energy_ddpc_kwh"]


@pytest.fixture
def hand_started_cluster(tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes, as an operator starts them."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = [open(tmp_path / f"dask{i}.log", "w") for i in range(3)]  # noqa: SIM115
    procs = [
        subprocess.Popen(
            [str(DASK), "scheduler", "--port", str(port), "--dashboard-address", ":0"],
            stdout=logs[0], stderr=subprocess.STDOUT,
        )
    ]  # fmt: skip
    for i in (1, 2):
        procs.append(
            subprocess.Popen(
                [str(DASK), "worker", address, "--nthreads", "1", "--nworkers", "1",
                 "--dashboard-address", ":0"],
                stdout=logs[i], stderr=subprocess.STDOUT,
            )
        )  # fmt: skip
    try:
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in logs:
            f.close()


def test_a_scheduler_with_two_workers_started_by_hand_gives_the_same_numbers(
    local, small_predictor_file, hand_started_cluster, capsys, tmp_path
):
    _, first = local
    remote = run_cli(
        capsys,
        study_argv(small_predictor_file, tmp_path / "remote", "--scheduler", hand_started_cluster),
    )
    assert remote["workers"] == 2 and remote["chunks_run"] == 4
    for key in ("energy_rule_kwh", "energy_ddpc_kwh", "savings_pct", "avg_hourly_violation_k"):
        assert math.isclose(remote[key], first[key], rel_tol=1e-6), key


def test_an_unreachable_scheduler_is_one_line_and_exit_2(small_predictor_file, capsys, monkeypatch,
                                                         tmp_path):  # fmt: skip
    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)
    address = f"tcp://127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    code, out, err = call(
        capsys, *study_argv(small_predictor_file, tmp_path, "--scheduler", address)
    )
    assert code == 2 and out == ""
    assert err.splitlines() == [
        f"trainclimate: error: cannot reach the Dask scheduler at {address}: "
        + err.split(f"{address}: ", 1)[1].strip()
    ]
    assert time.monotonic() - t0 < 30


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--controllers", "rule,edge"], "--controllers"),
        (["--scheduler", "localhost:8786"], "--scheduler"),
        (["--workers", "0"], "--workers"),
        (["--fleet", "no-such-fleet.json"], "--coaches N or --fleet"),
        (["--weather", "no-such.csv"], "weather"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(
    extra, needle, small_predictor_file, capsys, tmp_path
):
    code, out, err = call(capsys, *study_argv(small_predictor_file, tmp_path, *extra))
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and needle in err


def test_another_study_on_the_same_out_is_refused(local, small_predictor_file, capsys):
    out, _ = local
    code, _, err = call(capsys, *study_argv(small_predictor_file, out, "--seed", "7"))
    assert code == 2 and "holds a different study (seed: 2025 there, 7 here)" in err


def test_another_forecast_on_the_same_out_is_refused(local, small_predictor_file, capsys):
    out, _ = local
    code, _, err = call(capsys, *study_argv(small_predictor_file, out, "--forecast", "perfect"))
    assert code == 2 and "(forecast: persistence there, perfect here)" in err
    assert len(list((out / "chunks").iterdir())) == 4  # its chunks untouched


def test_a_fleet_file_gives_the_coaches_and_their_parameters(
    small_predictor_file, capsys, tmp_path
):
    from trainclimate.cli.study import fleet_from_file

    path = tmp_path / "fleet.json"
    own = CoachParams().to_dict() | {"supply_air_m3_h": 3000.0}
    path.write_text(json.dumps({"coaches": [{"coach": "124A", "params": own},
                                            {"coach": "44A", "params": {}}]}))  # fmt: skip
    ids, params = fleet_from_file(str(path))
    assert ids == ("124A", "44A") and params[0]["supply_air_m3_h"] == 3000.0
    path.write_text(json.dumps({"coaches": [{"coach": "1", "params": {"c_room_j_k": 1}}]}))
    code, _, err = call(capsys, "study", "fleet", "--fleet", str(path), "--out", str(tmp_path))
    assert code == 2 and "coach 1" in err


def test_a_failing_chunk_is_retried_then_named_and_the_others_kept(small_predictor, tmp_path):
    n = 2
    spec = StudySpec(
        coach_ids=("124A", "44A"),
        coach_params=(CoachParams().to_dict(),) * n,
        start="2025-01-14",
        days=2,
        chunk_days=1,
    )
    weather = study_weather(StudySpec(**{**spec.__dict__, "days": 1}))  # covers day 0 only
    with pytest.raises(ChunkError) as err:
        run_study(spec, tmp_path, weather=weather, predictor=small_predictor, workers=1)
    message = str(err.value)
    assert "1 chunk(s) failed after 2 retries" in message
    assert "coaches 124A…44A, days 2025-01-15…2025-01-15" in message
    assert [p.name for p in (tmp_path / "chunks").glob("*.parquet")] == [
        "c00000-00001_d000-000.parquet"
    ]


def test_a_parked_summer_day_counts_its_cooling_hours(small_predictor):
    spec = StudySpec(
        coach_ids=("A", "B"),
        coach_params=(CoachParams().to_dict(),) * 2,
        start="2025-07-16",
        days=1,
        parked_share=1.0,
    )
    frame = run_chunk(spec, spec.chunks()[0], study_weather(spec), small_predictor)
    hours = frame.groupby("situation")["hours"].sum()
    assert hours.sum() == pytest.approx(2 * 24.0)
    # a Zurich July day: the afternoon cools, the night (below T_ref − 8 K) heats
    assert hours.get("parked cooling", 0.0) > 2 * 4.0
    assert set(hours.index) <= {"parked cooling", "parked heating", "mixed mode"}
    assert "in service" not in hours and "off or slumber" not in hours
    assert (frame["regular_hours"] == frame["hours"]).all()


def test_a_twin_validated_for_summer_warns_in_a_january_study(
    small_predictor_file, capsys, tmp_path
):
    """A fleet file (calibrate --json) whose first coach's twin was validated at 15–32 °C only:
    the January weather leaves its range; the second, without a range, gets no such warning,
    but its response to setpoint changes is 40 % off: its savings are warned of."""
    fleet = tmp_path / "fleet.json"
    off = {"changes": 5, "scored": 4, "minutes": 600, "response_error_pct": 40.2}
    coaches = [
        {"coach": "124A", "params": {}, "validated_t_amb_c": [15.0, 32.0]},
        {"coach": "44A", "params": {}, "holdout": {"setpoint_response": off}},
    ]
    fleet.write_text(json.dumps({"coaches": coaches}))
    argv = study_argv(small_predictor_file, tmp_path / "out", "--workers", "1")
    argv[argv.index("--coaches") : argv.index("--coaches") + 2] = ["--fleet", str(fleet)]
    argv[argv.index("--days") + 1] = "1"
    code, out, err = call(capsys, *argv)
    assert code == 0, err
    [savings, warning] = json.loads(out)["warnings"]
    assert savings == (
        "--fleet: coach 44A: the savings predicted with the twin are not validated: its energy "
        "response to the 4 held-out setpoint changes is 40 % off (beyond 15 %)"
    )
    assert warning.startswith("the study's weather, 124A: T_amb ")
    assert "leaves the twin's validated range 15 to 32 °C for " in warning
    assert f"trainclimate: warning: {warning}" in err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["warnings"] == [savings, warning]
    coaches[0]["validated_t_amb_c"] = [15.0]
    fleet.write_text(json.dumps({"coaches": coaches}))
    argv[argv.index("--out") + 1] = str(tmp_path / "bad")
    code, out, err = call(capsys, *argv)
    assert code == 2 and out == "" and len(err.splitlines()) == 1
    assert "--fleet: coach 124A: validated_t_amb_c must be [low, high]" in err


def test_the_twin_at_its_intervals_ends_gives_the_savings_range(
    small_predictor_file, capsys, tmp_path
):
    """A twin calibrated with the envelope 1.2 [1.1, 1.3] and the fans without an interval:
    ``--twin-ends`` runs the study again with the envelope at 1.1 and at 1.3 (the fans as
    calibrated), the same seed and weather; the range spans every run's saving, the twin's own
    among them, and a leakier envelope costs more energy on both controllers."""
    twin = {
        **CoachParams().to_dict(),
        "twin": {
            "coach": "124A",
            "validated_t_amb_c": [-10.0, 30.0],
            "fitted": {
                "envelope_scale": {"value": 1.2, "std": 0.01, "ci95": [1.1, 1.3], "unit": "–"},
                "fan_supply_w": {"value": 1100.0, "std": 20.0, "unit": "W"},
            },
            "not_identified": [],
            "warnings": [],
        },
    }
    file = tmp_path / "twin.json"
    file.write_text(json.dumps(twin))
    argv = study_argv(small_predictor_file, tmp_path / "out", "--workers", "1", "--coach-params",
                      str(file), "--twin-ends")  # fmt: skip
    argv[argv.index("--coaches") + 1] = "2"
    argv[argv.index("--days") + 1] = "1"
    d = run_cli(capsys, argv)
    ends = d["twin_ends"]
    assert ends["without_interval"] == ["fan_supply_w"]
    assert [(r["param"], r["end"], r["value"]) for r in ends["runs"]] == [
        ("envelope_scale", "low", 1.1),
        ("envelope_scale", "high", 1.3),
    ]
    savings = [r["savings_pct"] for r in ends["runs"]] + [d["savings_pct"]]
    assert ends["savings_pct"] == [min(savings), max(savings)]
    low, high = ends["runs"]
    for key in ("energy_rule_kwh", "energy_ddpc_kwh"):
        assert low[key] < d[key] < high[key], key
    assert all(Path(r["out"], "study.json").is_file() for r in ends["runs"])
    # without a twin's file: one line, exit 2
    argv = study_argv(small_predictor_file, tmp_path / "none", "--twin-ends")
    code, out, err = call(capsys, *argv)
    assert code == 2 and out == "" and "--twin-ends needs --coach-params" in err
