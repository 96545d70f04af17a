"""Paired experiments (analysis.experiment.run_pair) on short parked runs: the pair shares its
disturbances, the activated coach saves energy, and the field events act and are excluded.

The runs (tests/analysis/conftest.py) are 3–8 h of a parked scenario at 10-s steps with the
controller every 5 min. Times below are local (Europe/Zurich). In parked-heating-nov (start
07:00) the controller's lead-in is complete at 08:00 (ρ = 12 samples, the first at 07:05), so the
layer is on from 08:00 and savings count from 08:45 (45 min to steady state).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from helpers.twin import twin_file
from trainclimate.analysis.experiment import (
    ACTIVATED,
    DEACTIVATED,
    EDGE,
    EXPERIMENTS,
    Event,
    ExperimentSetup,
    _event_masks,
    setup_for,
)
from trainclimate.cli import main
from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import VARIED, CoachParams

DOCUMENTED_KEYS = (
    "savings_pct",
    "avg_hourly_violation_k",
    "baseline_violation_k",
    "savings_30min_pct",
    "excluded_minutes",
    "edge_savings_pct",
)
ENV_FIELDS = (
    "t_amb_c",
    "ghi_w_m2",
    "q_roof_w_m2",
    "q_side_w_m2",
    "occupancy_pct",
    "speed_kmh",
    "door_open",
    "mode",
    "zenith_deg",
    "azimuth_deg",
    "heading_deg",
)
STEPS_PER_MIN = 6  # 10-s simulator steps


def local(result, clock: str) -> pd.Timestamp:
    return scenarios.local_clock(result.time[0], clock)


def span(result, a: str, b: str) -> np.ndarray:
    """The steps in [a, b) local."""
    return (result.time >= local(result, a)) & (result.time < local(result, b))


def counted_energy_kwh(pair, coach: int, drop: np.ndarray | None = None) -> float:
    """∫ P dt of a coach over the counted windows, straight from the simulation."""
    result, c = pair.result, pair.comparison
    end = c.window_start[0] + pd.Timedelta(minutes=c.window_min * len(c.window_start))
    rows = (result.time >= c.window_start[0]) & (result.time < end)
    if drop is not None:
        rows &= ~drop
    return float(result.meter_w("hvac")[rows, coach].sum() / 1e3 * result.dt_s / 3600.0)


def ticks_of(run, coach: int) -> list[tuple[int, str, str]]:
    log = run.loop.log.of_coach(coach)
    return [(k, r.source, r.reason) for k, r in zip(log.step, log.results, strict=True)]


# --- the pair -----------------------------------------------------------------------------------
def test_the_pair_shares_its_disturbances_exactly(heating_3h):
    result, loop = heating_3h.pair.result, heating_3h.loop
    env = result.env
    assert env.n_coaches == 3 and len(env.time) == 3 * 3600 // 10
    for name in ENV_FIELDS:
        value = getattr(env, name)
        for c in (DEACTIVATED, EDGE):
            np.testing.assert_array_equal(value[:, c], value[:, ACTIVATED], err_msg=name)
    # so are the rule curve's T_rule and what the controllers are told (interval means)
    np.testing.assert_array_equal(result.t_rule_c[:, DEACTIVATED], result.t_rule_c[:, ACTIVATED])
    np.testing.assert_array_equal(result.t_rule_c[:, EDGE], result.t_rule_c[:, ACTIVATED])
    np.testing.assert_array_equal(loop.d_true[:, DEACTIVATED], loop.d_true[:, ACTIVATED])
    # parked and empty, in regular mode throughout (the contract's parked-* scenarios)
    assert np.all(env.mode == MODE_REGULAR)
    assert np.all(env.speed_kmh == 0) and np.all(env.occupancy_pct == 0)
    assert np.ptp(env.t_amb_c[:, 0]) > 0.1 and env.ghi_w_m2[:, 0].max() > 10.0  # real weather


def test_coach_spread_zero_makes_twins(heating_3h):
    a, d, e = (p.to_dict() for p in heating_3h.params)
    assert a == d == e == CoachParams().to_dict()


def test_coach_spread_gives_the_deactivated_coach_parameters_of_its_own(record_pair):
    run = record_pair("parked-heating-nov", hours=1.5, coach_spread=0.1)
    a, d, e = (p.to_dict() for p in run.params)
    assert a == e == CoachParams().to_dict()  # the activated coach and its edge twin
    differ = {k for k in a if a[k] != d[k]}
    assert differ == set(VARIED)
    for name in ("c_room_j_k", "ua_room_inv_w_k", "area_ext_m2"):
        ratio = np.asarray(d[name]) / np.asarray(a[name])
        assert np.all((ratio >= 0.9) & (ratio <= 1.1)), name  # ±spread
    # the disturbances stay shared
    env = run.pair.result.env
    np.testing.assert_array_equal(env.t_amb_c[:, DEACTIVATED], env.t_amb_c[:, ACTIVATED])


# --- savings in short parked runs ---------------------------------------------------------------
@pytest.mark.parametrize("run_name", ["heating_3h", "cooling_energy_3h"])
def test_the_activated_coach_uses_less_energy(run_name, request):
    # measured: parked-heating-nov 4.8 % (band-edge 4.7 %), parked-cooling-aug-energy 8.4 %
    # (7.9 %) over the hour counted; > 1 % is well clear of the sensors' noise between twins
    pair = request.getfixturevalue(run_name).pair
    c, e = pair.comparison, pair.edge_comparison
    start = pair.result.time[0]
    assert pair.activated_at == start + pd.Timedelta(hours=1)  # the 1-h lead-in
    assert pair.counted_from == pair.activated_at + pd.Timedelta(minutes=45)
    # 3 h − 1 h 45 min: windows from +1:45 and +2:15
    assert list(c.window_start) == [pair.counted_from + pd.Timedelta(minutes=m) for m in (0, 30)]
    assert c.counted_hours == pytest.approx(1.0, rel=1e-12)
    assert not c.excluded.any() and c.excluded_minutes == 0.0
    # the totals are the simulation's energy over the counted hour
    assert c.energy_activated_total_kwh == pytest.approx(counted_energy_kwh(pair, ACTIVATED), 1e-12)
    deact = counted_energy_kwh(pair, DEACTIVATED)
    assert c.energy_deactivated_total_kwh == pytest.approx(deact, rel=1e-12)
    assert c.energy_activated_total_kwh < c.energy_deactivated_total_kwh
    assert c.savings_pct == pytest.approx(
        100 * (1 - c.energy_activated_total_kwh / c.energy_deactivated_total_kwh), rel=1e-12
    )
    assert 1.0 < c.savings_pct < 40.0
    assert all(s is not None and s > 0 for s in c.savings_30min_pct)
    # the band-edge reference against the same deactivated coach
    assert e.energy_deactivated_total_kwh == c.energy_deactivated_total_kwh
    assert e.savings_pct is not None and e.savings_pct > 1.0
    data = pair.to_dict()
    assert data["edge_savings_pct"] == e.savings_pct
    assert data["share_of_edge_pct"] == pytest.approx(100 * c.savings_pct / e.savings_pct)
    # the layer acted: T_ref left T_rule after activation, within the driver's ±2 K
    on = pair.result.time >= pair.activated_at
    gap = pair.result.t_ref_c[on, ACTIVATED] - pair.result.t_rule_c[on, ACTIVATED]
    assert 0.3 < np.abs(gap).max() <= 2.0 + 1e-12
    np.testing.assert_array_equal(pair.result.t_ref_c[:, DEACTIVATED], pair.result.t_rule_c[:, 1])


def test_experiment_settings_reach_the_controller(cooling_energy_3h):
    settings = cooling_energy_3h.pair.to_dict()["controller_settings"]
    assert (settings["sigma"], settings["tau"], settings["gamma"]) == (10.0, 1.0, 0.1)
    for controller in cooling_energy_3h.loop.controllers[::2]:  # the DDPC and the edge reference
        assert controller.settings.sigma == 10.0 and controller.settings.gamma == 0.1


def test_the_json_has_the_contract_keys(heating_3h):
    data = heating_3h.pair.to_dict()
    for key in DOCUMENTED_KEYS:
        assert key in data, key
    text = json.dumps(data)  # JSON without help: no numpy scalars, no NaN
    assert "NaN" not in text
    back = json.loads(text)
    assert back["scenario"] == "parked-heating-nov"
    assert isinstance(back["savings_pct"], float) and isinstance(back["edge_savings_pct"], float)
    assert len(back["savings_30min_pct"]) == len(back["window_start"]) == 2
    assert back["excluded_minutes"] == 0.0 and back["excluded_windows"] == [False, False]
    assert back["avg_hourly_violation_k"] >= 0.0 and back["baseline_violation_k"] >= 0.0
    assert back["counted_from"] == heating_3h.pair.counted_from.isoformat()
    assert back["controller_ticks"]["ticks"] == 35  # every 5 min from 07:05 to 09:55


# --- the command override of parked-heating-nov -------------------------------------------------
def test_the_scenario_setups():
    nov = EXPERIMENTS["parked-heating-nov"]
    assert nov.events == (Event("command_override", "activated", "13:30", 30.0),)
    assert setup_for("parked-heating-nov") is nov
    assert setup_for("no-such-scenario") == ExperimentSetup()
    assert EXPERIMENTS["parked-cooling-aug-conservative"].ocp_settings().t_max == 0.6
    assert EXPERIMENTS["parked-cooling-oct"].activate_at == "13:15"


def test_the_command_override_forces_t_rule_and_excludes_its_windows(heating_override):
    pair = heating_override.pair
    result, c = pair.result, pair.comparison
    override = span(result, "13:30", "14:00")
    assert override.sum() == 30 * STEPS_PER_MIN
    np.testing.assert_array_equal(pair.affected[:, ACTIVATED], override)
    np.testing.assert_array_equal(pair.affected[:, EDGE], override)
    assert not pair.affected[:, DEACTIVATED].any()
    # the commands overwritten: the HVAC ran on T_rule exactly, both coaches with a controller
    for coach in (ACTIVATED, EDGE):
        np.testing.assert_array_equal(result.t_ref_c[override, coach], result.t_rule_c[override, 0])
    # … which it did not before (the layer was acting in the half hour before)
    before = span(result, "13:00", "13:30")
    assert np.abs(result.t_ref_c[before, ACTIVATED] - result.t_rule_c[before, 0]).max() > 0.1
    # windows from 08:45 local: 13:15–13:45 and 13:45–14:15 touch the override
    assert len(c.window_start) == 12 and c.window_start[0] == local(result, "08:45")
    assert np.flatnonzero(c.excluded).tolist() == [9, 10]
    assert [c.window_start[w] for w in (9, 10)] == [local(result, "13:15"), local(result, "13:45")]
    assert [i for i, s in enumerate(c.savings_30min_pct) if s is None] == [9, 10]
    assert c.excluded_minutes == 60.0 and c.affected_minutes == 30.0
    assert np.array_equal(pair.edge_comparison.excluded, c.excluded)
    # the telemetry still arrived: the controller kept computing, nothing went stale
    in_override = [r for k, s, r in ticks_of(heating_override, ACTIVATED) if override[k]]
    assert in_override == ["ok"] * 6
    # the totals leave the excluded windows out
    counted = ~np.repeat(c.excluded, 30 * STEPS_PER_MIN)
    rows = np.flatnonzero(result.time >= c.window_start[0])[: counted.size][counted]
    e_act = result.meter_w("hvac")[rows, ACTIVATED].sum() / 1e3 * result.dt_s / 3600.0
    assert c.energy_activated_total_kwh == pytest.approx(e_act, rel=1e-12)
    assert c.savings_pct is not None and c.savings_pct > 1.0


# --- a connection loss --------------------------------------------------------------------------
def test_a_connection_loss_drops_the_coachs_data_and_its_commands(heating_loss):
    pair = heating_loss.pair
    result, c = pair.result, pair.comparison
    lost_act = span(result, "09:00", "09:15")
    lost_deact = span(result, "09:50", "10:00")
    np.testing.assert_array_equal(pair.affected[:, ACTIVATED], lost_act)
    np.testing.assert_array_equal(pair.affected[:, EDGE], lost_act)
    np.testing.assert_array_equal(pair.affected[:, DEACTIVATED], lost_deact)
    # no command reached the HVAC: T_ref = T_rule while cut off
    for coach in (ACTIVATED, EDGE):
        np.testing.assert_array_equal(result.t_ref_c[lost_act, coach], result.t_rule_c[lost_act, 0])
    # windows 08:45, 09:15, 09:45 (10:15–10:30 incomplete): the first and the last lost data
    assert [str(t.tz_convert(scenarios.LOCAL_TZ).time()) for t in c.window_start] == [
        "08:45:00",
        "09:15:00",
        "09:45:00",
    ]
    assert c.excluded.tolist() == [True, False, True]
    assert c.savings_30min_pct[0] is None and c.savings_30min_pct[2] is None
    assert c.savings_30min_pct[1] is not None
    assert c.excluded_minutes == 60.0 and c.affected_minutes == 25.0
    # no logger data while cut off: the lost minutes carry no energy (power NaN)
    w0 = span(result, "08:45", "09:15")
    dt_h = result.dt_s / 3600.0
    expected = result.meter_w("hvac")[w0 & ~lost_act, ACTIVATED].sum() / 1e3 * dt_h
    assert c.energy_activated_kwh[0] == pytest.approx(expected, rel=1e-12)
    full = result.meter_w("hvac")[w0, ACTIVATED].sum() / 1e3 * dt_h
    assert c.energy_activated_kwh[0] < full - 0.1  # a heating coach draws > 1 kW
    assert c.energy_deactivated_kwh[0] == pytest.approx(
        result.meter_w("hvac")[w0, DEACTIVATED].sum() / 1e3 * dt_h, rel=1e-12
    )
    w2 = span(result, "09:45", "10:15")
    expected = result.meter_w("hvac")[w2 & ~lost_deact, DEACTIVATED].sum() / 1e3 * dt_h
    assert c.energy_deactivated_kwh[2] == pytest.approx(expected, rel=1e-12)
    # only window 09:15 counts
    assert c.energy_activated_total_kwh == pytest.approx(c.energy_activated_kwh[1], rel=1e-12)
    assert c.savings_pct == pytest.approx(c.savings_30min_pct[1], rel=1e-12)


def test_the_controller_gets_no_samples_while_cut_off(heating_loss):
    result = heating_loss.pair.result
    lost = span(result, "09:00", "09:15")
    start = local(result, "09:00")
    for coach in (ACTIVATED, EDGE):
        ticks = ticks_of(heating_loss, coach)
        during = [(k, r) for k, s, r in ticks if lost[k]]
        # ticks at 09:00, 09:05, 09:10; from the second one the last sample is ≥ 2 periods old
        assert [result.time[k] for k, _ in during] == [
            start + pd.Timedelta(minutes=m) for m in (0, 5, 10)
        ]
        assert [r for _, r in during[1:]] == ["stale", "stale"]
        # reconnected at 09:15: the samples have a gap, so the controller waits for ρ new ones
        after = [r for k, s, r in ticks if result.time[k] >= local(result, "09:15")]
        assert after[0] == "missing_samples"
    assert heating_loss.pair.ticks["reasons"]["stale"] == 2  # the activated coach's summary


# --- activation time and events -----------------------------------------------------------------
def test_before_activation_the_coach_runs_on_t_rule(record_pair):
    run = record_pair("parked-heating-nov", hours=3.0, setup=ExperimentSetup(activate_at="08:30"))
    pair, loop = run.pair, run.loop
    result = pair.result
    on = 90 * STEPS_PER_MIN  # 08:30 is 90 min after the 07:00 start
    assert loop.active_from.tolist() == [on] * 3
    assert pair.activated_at == local(result, "08:30") == result.time[on]
    assert pair.counted_from == local(result, "09:15")
    assert pair.to_dict()["activated_at"] == pair.activated_at.isoformat()
    for coach in (ACTIVATED, EDGE):
        np.testing.assert_array_equal(result.t_ref_c[:on, coach], result.t_rule_c[:on, 0])
        ticks = ticks_of(run, coach)
        before = [(s, r) for k, s, r in ticks if k < on]
        # every tick from 07:05 to 08:25: switched off (lead-in and all)
        assert before == [("rule", "inactive")] * 17
        assert [r for k, s, r in ticks if k >= on][:3] == ["ok"] * 3
    gap = result.t_ref_c[on:, ACTIVATED] - result.t_rule_c[on:, 0]
    assert np.abs(gap).max() > 0.3  # and then it acts
    assert pair.ticks["reasons"]["inactive"] == 17 and "warmup" not in pair.ticks["reasons"]


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"kind": "power_cut", "coach": "activated", "start": "09:00"}, "unknown event kind"),
        ({"kind": "connection_loss", "coach": "edge", "start": "09:00"}, "coach"),
        ({"kind": "command_override", "coach": "both", "start": "09:00"}, "coach"),
    ],
)
def test_bad_events_are_refused(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        Event(**kwargs)


def test_events_to_the_end_and_on_the_next_day():
    env1, _ = scenarios.build(scenarios.get("parked-heating-nov"), hours=24.5)  # to 07:30 +1
    env = Environment.side_by_side([env1] * 3)
    setup = ExperimentSetup(
        events=(
            Event("connection_loss", "deactivated", "16:00"),  # no duration: to the end
            Event("command_override", "activated", "07:10+1", 15.0),
        )
    )
    lost, overridden = _event_masks(setup, env)
    assert lost.shape == overridden.shape == (len(env.time), 3)
    k = np.arange(len(env.time))
    np.testing.assert_array_equal(lost[:, DEACTIVATED], k >= 9 * 3600 // 10)
    assert not lost[:, [ACTIVATED, EDGE]].any()
    rows = (k >= 1450 * STEPS_PER_MIN) & (k < 1465 * STEPS_PER_MIN)  # 07:10–07:25 the next day
    for coach in (ACTIVATED, EDGE):
        np.testing.assert_array_equal(overridden[:, coach], rows)
    assert not overridden[:, DEACTIVATED].any()


# --- the command --------------------------------------------------------------------------------
def call(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def run_cli(capsys, predictor_file, *argv):
    return call(
        capsys,
        "experiment",
        "run",
        "--scenario",
        "parked-heating-nov",
        "--predictor",
        str(predictor_file),
        *argv,
    )


def test_experiment_run_prints_the_contract_keys(capsys, small_predictor_file, heating_3h):
    code, out, err = run_cli(capsys, small_predictor_file, "--hours", "3", "--json")
    assert code == 0, err
    assert len(out.strip().splitlines()) == 1
    data = json.loads(out)
    for key in DOCUMENTED_KEYS:
        assert key in data, key
    # the same run as the fixture's, the model read back from its file
    expected = heating_3h.pair.to_dict()
    for key in (
        "savings_pct",
        "edge_savings_pct",
        "avg_hourly_violation_k",
        "baseline_violation_k",
    ):
        assert data[key] == pytest.approx(expected[key], rel=1e-9), key
    assert data["savings_30min_pct"] == pytest.approx(expected["savings_30min_pct"], rel=1e-9)
    assert data["excluded_minutes"] == 0.0 and data["scenario"] == "parked-heating-nov"
    assert "html" not in data
    # the layer's default objective, and the paper's on request
    assert data["controller_settings"]["objective"] == "states"
    code, out, err = run_cli(
        capsys, small_predictor_file, "--hours", "3", "--objective", "paper", "--json"
    )
    assert code == 0, err
    assert json.loads(out)["controller_settings"]["objective"] == "paper"


def test_experiment_run_writes_the_report(capsys, small_predictor_file, tmp_path):
    html = tmp_path / "reports" / "nov.html"
    code, out, err = run_cli(
        capsys, small_predictor_file, "--hours", "2", "--html", str(html), "--json"
    )
    assert code == 0, err
    data = json.loads(out)
    assert data["html"] == str(html.resolve()) and html.exists()
    assert "parked-heating-nov: activated vs deactivated" in html.read_text(encoding="utf-8")
    # 2 h: counted from 07:45 UTC to 08:00 UTC, no complete window, no savings yet
    assert data["savings_pct"] is None and data["edge_savings_pct"] is None
    assert data["savings_30min_pct"] == [] and data["excluded_minutes"] == 0.0
    code, out, err = run_cli(capsys, small_predictor_file, "--hours", "2")
    assert code == 0, err
    assert out.startswith(
        "parked-heating-nov: savings – on the hvac meter, – with the floor heating (band-edge "
        "reference –)"
    )


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (("--scenario", "parked-nowhere"), "unknown scenario"),
        (("--hours", "0"), "--hours"),
        (("--hours", "nan"), "--hours"),
        (("--coach-spread", "1.5"), "--coach-spread"),
        (("--coach-spread", "-0.1"), "--coach-spread"),
        (("--predictor", "no-such-model.npz"), "model file not found"),
        (("--forecast", "oracle"), "--forecast"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(capsys, small_predictor_file, argv, needle):
    code, out, err = run_cli(capsys, small_predictor_file, "--hours", "1", *argv, "--json")
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and needle in err


def test_experiment_run_warns_when_the_scenario_leaves_the_twins_range(
    capsys, small_predictor_file, tmp_path
):
    args = ["--hours", "0.5", "--json"]
    summer = twin_file(tmp_path / "summer.json", [18.0, 33.0])
    code, out, err = run_cli(capsys, small_predictor_file, *args, "--coach-params", str(summer))
    assert code == 0, err
    [warning] = json.loads(out)["warnings"]
    assert warning.startswith("scenario parked-heating-nov: T_amb ")
    assert f"trainclimate: warning: {warning}" in err
    winter = twin_file(tmp_path / "winter.json", [-15.0, 15.0])
    code, out, err = run_cli(capsys, small_predictor_file, *args, "--coach-params", str(winter))
    assert code == 0 and json.loads(out)["warnings"] == [] and "warning" not in err
    # in its range, but its response to setpoint changes untested: its savings are warned of
    one_change = {"changes": 2, "scored": 1, "minutes": 130, "response_error_pct": 4.0}
    untested = twin_file(tmp_path / "untested.json", [-15.0, 15.0], one_change)
    code, out, err = run_cli(capsys, small_predictor_file, *args, "--coach-params", str(untested))
    assert code == 0, err
    assert json.loads(out)["warnings"] == [
        f"--coach-params {untested}: the savings predicted with the twin are not validated: its "
        "response to a setpoint change is untested: the held-out days hold 1 scored change(s), "
        "3 needed"
    ]
    bad = twin_file(tmp_path / "bad.json", [15.0, "x"])
    code, out, err = run_cli(capsys, small_predictor_file, *args, "--coach-params", str(bad))
    assert code == 2 and out == "" and "validated_t_amb_c must be" in err
    assert len(err.strip().splitlines()) == 1
