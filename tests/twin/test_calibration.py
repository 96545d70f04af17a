"""Calibrating the simulator to a coach: the replay of its logs, the fit on generated logs of
known parameters, and every refusal."""

import contextlib
import dataclasses
import io
import json

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import OptimizeResult

from helpers.cli import call, call_json
from trainclimate.cli import main
from trainclimate.data import fleetlogs
from trainclimate.data.dataset import build_dataset
from trainclimate.data.trajectory import Trajectory, read_trajectories
from trainclimate.sim.params import CoachParams, load_params
from trainclimate.twin import fit as fit_module
from trainclimate.twin import replay, validation
from trainclimate.twin.calibration import calibrate
from trainclimate.twin.knobs import CalibrationError, apply

#: The coach whose logs are generated: its envelope and supply fans 20 % and 25 % off the default.
TRUTH = {"envelope_scale": 1.2, "fan_supply_w": 1.25 * CoachParams().fan_supply_w}


@pytest.fixture(scope="module")
def winter_dataset(tmp_path_factory):
    """1-min trajectories of coaches 124A (in the depot the first day) and 44A, 6 winter days,
    generated with :data:`TRUTH`."""
    root = tmp_path_factory.mktemp("calibration")
    truth = apply(CoachParams(), TRUTH)
    fleetlogs.generate(
        root / "raw", campaigns=(fleetlogs.WINTER_SPRING,), max_days=6, max_coaches=2,
        coach_params=truth,
    )  # fmt: skip
    build_dataset(root / "raw", root / "out")
    return root / "out"


@pytest.fixture(scope="module")
def winter(winter_dataset):
    return read_trajectories(winter_dataset / "trajectories_1min.parquet")


def test_apply_scales_the_envelope_capacities_aperture_and_cop():
    base = CoachParams()
    p = apply(
        base,
        {"envelope_scale": 2.0, "capacity_scale": 0.5, "solar_scale": 1.5, "cop_level": 0.8},
    )
    np.testing.assert_allclose(p.area_ext_m2, 2 * base.area_ext_m2)
    # the outer envelope doubles; the middle floor's interior film does not
    np.testing.assert_allclose(
        p.ua_room_chassis_w_k, [[2, 1, 1], [2, 1, 2], [1, 1, 2]] * base.ua_room_chassis_w_k
    )
    np.testing.assert_allclose(p.c_chassis_j_k, 0.5 * base.c_chassis_j_k)
    assert (p.window_g, p.roof_absorptance) == pytest.approx((0.6, 0.9))
    assert (p.cop_a, p.cop_b, p.cop_max) == pytest.approx((3.52, 0.048, 3.6))
    with pytest.raises(CalibrationError, match="unknown calibration parameter 'u_value'"):
        apply(base, {"u_value": 1.0})


def test_the_doors_open_at_stops_and_at_the_ends_of_a_turnaround():
    speed = np.array([80, 0, 0, 80, 0, 0, 0, 0, 0, 0, 80, 0], dtype=float)[:, None]
    occ = np.array([30, 30, 30, 30, 0, 0, 0, 0, 0, 0, 20, 0], dtype=float)[:, None]
    doors = replay._doors(speed, occ)[:, 0]
    # a stop (standing on a trip); a 6-min turnaround: its first and last 2 min; the
    # standstill at the end is not known to be a turnaround
    np.testing.assert_array_equal(doors, [0, 1, 1, 0, 1, 1, 0, 0, 1, 1, 0, 0])
    # a 2-s log knows a 40-s stop inside a minute whose mean speed is 30 km/h
    share = np.array([0, 1, 1, 2 / 3, 1, 1, 1, 1, 1, 1, 0.25, 1])[:, None]
    doors = replay._doors(np.where(share > 0.5, 30.0, speed), occ, share)[:, 0]
    np.testing.assert_allclose(doors, [0, 1, 1, 2 / 3, 0, 0, 0, 0, 0, 0, 0.25, 0])


def test_the_replay_reproduces_the_logged_disturbances():
    n = 90
    time = pd.date_range("2022-03-01 10:00", periods=n, freq="1min", tz="UTC")
    d = np.column_stack(
        [np.full(n, 3.0), np.linspace(0, 400, n), np.linspace(200, 0, n), np.full(n, 25.0),
         np.where(np.arange(n) % 10 < 5, 60.0, 0.0)]
    )  # fmt: skip
    y = np.full((n, 3), 21.0)
    traj = Trajectory(time, y, np.full((n, 1), 22.0), d, "c", "1", "1A", 1, p_kw=np.full(n, 5.0))
    rep = replay.replay([traj])
    per = rep.per_minute
    np.testing.assert_allclose(rep.env.q_roof_w_m2[::per, 0], d[:, 1], atol=0.05)
    np.testing.assert_allclose(rep.env.q_side_w_m2[::per, 0], d[:, 2], atol=1e-9)
    np.testing.assert_allclose(rep.env.t_amb_c[::per, 0], 3.0)
    np.testing.assert_allclose(rep.t_ref_c[::per, 0], 22.0)
    assert rep.scored[: replay.WARMUP_MIN].sum() == 0 and rep.scored[replay.WARMUP_MIN :].all()


@pytest.fixture(scope="module")
def envelope_cli(winter_dataset, tmp_path_factory):
    """``calibrate --params envelope_scale`` of 44A, the fans' power known (from the nameplate,
    ``--base-params``): its ``--json`` object and the coach-params file it wrote; one fit for the
    two tests below (≈ 2 min)."""
    tmp = tmp_path_factory.mktemp("envelope")
    out, known = tmp / "44A.json", tmp / "known.json"
    known.write_text(json.dumps({"fan_supply_w": TRUTH["fan_supply_w"]}))
    argv = [
        "calibrate", "--data", str(winter_dataset), "--coach", "44A",
        "--params", "envelope_scale", "--base-params", str(known), "--starts", "1",
        "--bootstrap", "3", "--out", str(out), "--json",
    ]  # fmt: skip
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(argv) == 0
    return json.loads(buf.getvalue()), out


@pytest.mark.slow  # 12 simulated coach-days, then a fit
def test_a_known_envelope_is_recovered_from_generated_logs(envelope_cli):
    """The envelope 20 % above the default, the fans' power known (from the nameplate)."""
    data, _ = envelope_cli
    [fit] = data["coaches"]
    known = CoachParams(fan_supply_w=TRUTH["fan_supply_w"])
    envelope = fit["fitted"]["envelope_scale"]
    assert envelope["value"] == pytest.approx(TRUTH["envelope_scale"], rel=0.05)
    assert 0 < envelope["std"] < 0.05
    # the twin predicts the held-out day's metered energy
    assert abs(fit["holdout"]["energy_error_pct"]) < 5.0
    assert fit["holdout"]["t_room_mae_c"] < 0.3 and fit["holdout"]["minutes"] > 300
    # the parameters are a whole coach-params set, the fitted fields replaced
    expected = apply(known, {"envelope_scale": envelope["value"]})
    assert fit["params"] == expected.to_dict()
    assert not [w for w in fit["warnings"] if "stopped short of a minimum" in w]


def _stuck(fun, x0, jac, **_):
    """``least_squares`` stopping where it starts, as it does on a kink of the error with its
    ``xtol`` test met."""
    r = fun(x0)
    message = "`xtol` termination condition is satisfied."
    return OptimizeResult(x=x0, fun=r, jac=jac(x0), cost=0.5 * r @ r, message=message)


@pytest.mark.slow  # 12 simulated coach-days, a compass search
def test_a_fit_stuck_at_its_start_is_continued_by_a_compass_search(winter, monkeypatch):
    """The envelope fit of the first test with an optimiser that never leaves its start: the
    compass search takes it to the truth all the same, and nothing is warned of."""
    monkeypatch.setattr(fit_module, "least_squares", _stuck)
    mine = [t for t in winter if t.coach == "44A"]
    known = CoachParams(fan_supply_w=TRUTH["fan_supply_w"])
    fit = calibrate("44A", mine, ("envelope_scale",), base=known, starts=1, bootstrap=0)
    assert fit.fitted["envelope_scale"]["value"] == pytest.approx(TRUTH["envelope_scale"], rel=0.05)
    assert not [w for w in fit.warnings if "stopped short of a minimum" in w]


@pytest.mark.slow  # 12 simulated coach-days
def test_a_fit_left_stuck_is_warned_of(winter, monkeypatch):
    """Without the compass search (no rounds) the stuck fit stays at the best screened start,
    which is not passed off as the coach's: the warning says how much a step would still
    gain."""
    monkeypatch.setattr(fit_module, "least_squares", _stuck)
    monkeypatch.setattr(fit_module, "COMPASS_ROUNDS", 0)
    mine = [t for t in winter if t.coach == "44A"]
    known = CoachParams(fan_supply_w=TRUTH["fan_supply_w"])
    fit = calibrate("44A", mine, ("envelope_scale",), base=known, starts=1, bootstrap=0)
    assert fit.fitted["envelope_scale"]["value"] != pytest.approx(TRUTH["envelope_scale"], rel=0.02)
    (warning,) = [w for w in fit.warnings if "stopped short of a minimum" in w]
    assert "(`xtol` termination condition is satisfied)" in warning
    share = int(warning.split("predicts ")[1].split("%")[0])
    assert share > 100 * fit_module.STALLED_SHARE


def test_the_compass_search_gets_past_kinks_within_the_bounds():
    """|z₀ − 0.7| + |z₁ − 1.3| has a kink at its minimum (a gradient method's step test stops
    anywhere near it); the compass search ends within its finest step, and never leaves the
    bounds (the second minimum lies beyond z₁ ≤ 1.2: it stops at the bound)."""

    def residuals(points):
        return [np.array([abs(z[0] - 0.7) + abs(z[1] - 1.3)]) for z in points]

    lo, z0 = np.zeros(2), np.array([1.0, 1.0])
    z, r = fit_module.compass(residuals, z0, residuals([z0])[0], lo, np.full(2, 3.0))
    finest = fit_module.COMPASS_FINEST * np.maximum(np.abs(z0), 0.1)
    np.testing.assert_array_less(np.abs(z - [0.7, 1.3]), 2 * finest)
    assert r[0] < 2 * finest.sum()
    z, _ = fit_module.compass(residuals, z0, residuals([z0])[0], lo, np.array([3.0, 1.2]))
    assert z[1] == pytest.approx(1.2) and abs(z[0] - 0.7) < 2 * finest[0]


def test_the_predicted_fall_of_a_linear_problem():
    """r(z) = A z − b: from the optimum a Gauss–Newton step removes nothing; from elsewhere it
    removes exactly what lies between; at a bound the optimum lies beyond, nothing either."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(40, 3)), rng.normal(size=40)
    lo, hi = np.full(3, -10.0), np.full(3, 10.0)
    best = np.linalg.lstsq(a, b, rcond=None)[0]
    r_best = a @ best - b
    assert fit_module.predicted_fall(r_best, a, best, lo, hi) == pytest.approx(0.0, abs=1e-12)
    z = best + np.array([0.5, -0.3, 0.2])
    r = a @ z - b
    expected = 1.0 - (r_best @ r_best) / (r @ r)
    assert fit_module.predicted_fall(r, a, z, lo, hi) == pytest.approx(expected, rel=1e-9)
    # the unconstrained optimum at 2 in the first coordinate, the bound at 1: stopped there
    eye, target = np.eye(2), np.array([2.0, 0.0])
    at_bound = np.array([1.0, 0.0])
    r = eye @ at_bound - target
    assert fit_module.predicted_fall(r, eye, at_bound, np.zeros(2), np.ones(2)) == 0.0
    assert fit_module.predicted_fall(np.zeros(3), a, best, lo, hi) == 0.0


@pytest.mark.slow  # 12 simulated coach-days
def test_by_default_what_winter_days_do_not_identify_is_held_at_its_base(winter, monkeypatch):
    """Among the envelope and the COP, winter days identify the envelope only: the COP is kept
    at its base value and reported, not refused. 44A's coldest and warmest of its 3 days are
    held out: one training day, which a bootstrap over days cannot resample (a warning); the
    held-out days get their errors per ambient band. (The optimiser is held at its start: what
    is held, bootstrapped and scored here does not depend on where the fit ends, which the
    first test checks.)"""
    monkeypatch.setattr(fit_module, "least_squares", _stuck)
    monkeypatch.setattr(fit_module, "COMPASS_ROUNDS", 0)
    mine = [t for t in winter if t.coach == "44A"]
    known = CoachParams(fan_supply_w=TRUTH["fan_supply_w"])
    fit = calibrate(
        "44A", mine, base=known, starts=1, bootstrap=3, among=("envelope_scale", "cop_level")
    )
    assert fit.not_identified == [
        {"param": "cop_level", "reason": "nothing logged on the training days depends on it"}
    ]
    assert fit.params.cop_a == known.cop_a
    assert "ci95" not in fit.fitted["envelope_scale"] and fit.bootstrap == 0
    assert "one training day: no bootstrap interval (it resamples whole days)" in fit.warnings
    bands = fit.holdout["bands"]
    assert bands and sum(b["minutes"] for b in bands) <= fit.holdout["minutes"]


def test_winter_days_cannot_calibrate_the_compressor_a_refusal(winter):
    mine = [t for t in winter if t.coach == "44A"]
    with pytest.raises(CalibrationError, match="depends on cop_level"):
        calibrate("44A", mine, ("cop_level", "fan_supply_w"), starts=1)


def test_too_little_data_is_a_refusal(winter):
    mine = [t for t in winter if t.coach == "44A"]
    one_day = [t for t in mine if t.time[0].date() == mine[0].time[0].date()]
    with pytest.raises(CalibrationError, match="at least 2 days"):
        calibrate("44A", one_day)
    short = [
        Trajectory(t.time[:90], t.y[:90], t.u[:90], t.d[:90], t.campaign, t.train, t.coach, 1,
                   p_kw=t.p_kw[:90])
        for t in mine
    ]  # fmt: skip
    with pytest.raises(CalibrationError, match="scored training minutes"):
        calibrate("44A", short)
    unmetered = [dataclasses.replace(t, p_kw=None) for t in mine]
    with pytest.raises(CalibrationError, match="no metered HVAC power"):
        calibrate("44A", unmetered)
    with pytest.raises(CalibrationError, match="unknown calibration parameter 'ua'"):
        calibrate("44A", mine, ("ua",))


def test_calibrate_command_errors_are_one_line_exit_2(capsys, winter_dataset, tmp_path):
    data = ["--data", str(winter_dataset)]
    for args, needle in (
        (["--params", "u_value"], "--params: unknown 'u_value'; choose from envelope_scale"),
        (["--coach", "44A", "124A", "--out", str(tmp_path / "p.json")], "exactly one --coach"),
        (["--coach", "99Z"], "no trajectories of coach '99Z'"),
        (["--starts", "0"], "--starts must be at least 1"),
        (["--bootstrap", "-1"], "--bootstrap must not be negative"),
        (["--coach", "44A", "--params", "cop_level"], "depends on cop_level"),
        (["--data", str(tmp_path)], "holds no dataset"),
    ):
        code, out, err = call(capsys, "calibrate", *data, *args, "--json")
        assert code == 2 and out == "" and needle in err, (args, err)
        assert len(err.strip().splitlines()) == 1


@pytest.mark.slow  # the envelope's fit
def test_calibrate_writes_a_coach_params_file_the_simulator_takes(capsys, envelope_cli):
    data, out = envelope_cli
    [coach] = data["coaches"]
    assert set(coach) >= {"coach", "params", "fitted", "train", "holdout", "warnings"}
    assert coach["not_identified"] == []
    # the file carries the calibration's record beside the parameters
    record = json.loads(out.read_text())["twin"]
    assert record["validated_t_amb_c"] == coach["validated_t_amb_c"]
    assert record["fitted"] == coach["fitted"] and record["warnings"] == coach["warnings"]
    assert record["holdout"] == coach["holdout"]  # the setpoint changes' score among it
    assert set(coach["holdout"]) >= {"t_room_mae_c", "power_mae_kw", "energy_error_pct"}
    response = coach["holdout"]["setpoint_response"]
    assert set(response) >= {"changes", "scored", "minutes", "response_error_pct"}
    assert response["minutes"] <= coach["holdout"]["minutes"]
    assert coach["fitted"]["envelope_scale"]["value"] == pytest.approx(1.2, rel=0.05)
    assert load_params(out).to_dict() == coach["params"]
    result = call_json(
        capsys, "simulate", "--scenario", "parked-heating-nov", "--hours", "1",
        "--coach-params", str(out),
    )  # fmt: skip
    assert result["energy_kwh"] > 0


@pytest.mark.slow  # 16 generated coach-days, then a fit of three parameters (~2 min)
def test_envelope_cop_and_fans_differing_by_20_to_25_percent_come_back_within_20(tmp_path):
    """A coach whose envelope, COP level and supply fans are 20 %, −20 % and 25 % off the
    default, logged 8 winter and 8 summer days (as 124A and 124B: one coach), the coldest and
    warmest days held out. Measured: +4 %, −13 %, −17 %: the COP level and the fans share the
    electrical power, and the HVAC state the room chooses is history-dependent, which the replay
    cannot know from the logs (docs/model.md); the held-out energy is still within 1 %."""
    truth = {"envelope_scale": 1.2, "cop_level": 0.8, "fan_supply_w": 1.25 * 1100.0}
    fleetlogs.generate(
        tmp_path / "raw", max_days=8, max_coaches=1, coach_params=apply(CoachParams(), truth)
    )
    build_dataset(tmp_path / "raw", tmp_path / "out")
    trajectories = read_trajectories(tmp_path / "out" / "trajectories_1min.parquet")
    fit = calibrate("124A+124B", trajectories, tuple(truth), starts=1, bootstrap=0)
    assert fit.fitted["envelope_scale"]["value"] == pytest.approx(1.2, rel=0.05)
    for name, value in truth.items():
        assert fit.fitted[name]["value"] == pytest.approx(value, rel=0.20), name
    # the twin predicts the held-out days' HVAC energy within 5 %
    assert abs(fit.holdout["energy_error_pct"]) < 5.0 and fit.holdout["minutes"] > 1000


def _day(date: str, t_amb_c: float, coach: str = "1A") -> Trajectory:
    """A 2-h trajectory on the local ``date`` at a constant ``t_amb_c``."""
    n = 120
    time = pd.date_range(f"{date} 10:00", periods=n, freq="1min", tz="UTC")
    d = np.column_stack([np.full(n, t_amb_c), np.zeros((n, 3)), np.full(n, 60.0)])
    y, u = np.full((n, 3), 21.0), np.full((n, 1), 22.0)
    return Trajectory(time, y, u, d, "c", "1", coach, 1, p_kw=np.full(n, 5.0))


def test_the_coldest_and_the_warmest_days_are_held_out():
    winter = {"2022-02-01": 2.0, "2022-02-02": -6.0, "2022-02-03": 5.0, "2022-02-04": 0.0}
    summer = {"2023-07-04": 31.0, "2023-07-05": 24.0, "2023-07-06": 27.0, "2023-07-07": 22.0}
    temps = {**winter, **summer}
    train, held = validation.split_days([_day(d, t) for d, t in temps.items()])
    assert sorted(t.d[0, 0] for t in held) == [-6.0, 31.0]
    assert len(train) == 6
    # from 12 days on a third day is held out: the next coldest
    temps.update({"2023-07-08": 25.0, "2023-07-09": 26.0, "2022-02-05": 1.0, "2022-02-06": 3.0})
    _, held = validation.split_days([_day(d, t) for d, t in temps.items()])
    assert sorted(t.d[0, 0] for t in held) == [-6.0, 0.0, 31.0]


def _band(low: float, energy_error_pct: float | None) -> dict:
    return {"t_amb_c": [low, low + validation.BAND_K], "energy_error_pct": energy_error_pct}


def test_the_validated_range_grows_by_good_held_out_bands_and_stops_at_a_bad_one():
    train = np.linspace(0.0, 12.0, 1000)  # the training minutes' T_amb
    validated, warnings = validation.validated_range(train, [])
    assert validated == pytest.approx([0.2, 11.8], abs=0.05) and warnings == []
    # a good band below, a bad one beyond it; a good band above
    bands = [_band(-5.0, 2.0), _band(-10.0, -12.0), _band(10.0, 1.0), _band(15.0, 4.9)]
    validated, warnings = validation.validated_range(train, bands)
    assert validated == [-5.0, 20.0]
    assert warnings == [
        "held out at -10 to -5 °C the twin's energy is -12.0 % off (beyond ±5 %): not "
        "validated there"
    ]
    # a bad band inside the training range cuts it on its side
    validated, _ = validation.validated_range(train, [_band(10.0, 8.0)])
    assert validated == pytest.approx([0.2, 10.0], abs=0.05)
    validated, warnings = validation.validated_range(train, [_band(0.0, 8.0), _band(5.0, 9.0)])
    assert validated is None and warnings[-1] == "the twin is validated at no ambient temperature"
