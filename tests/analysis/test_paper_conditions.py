"""Table II under the paper's own conditions: both meters, the October experiment cooling, the
field events as reported, the violation from the sensors, and the ablation that adds them in
order (analysis.experiment, analysis.ablation).

Runs as in test_experiment.py (tests/analysis/conftest.py): parked scenarios at 10-s steps, the
controller every 5 min, the session's small predictor. Times are local (Europe/Zurich).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from trainclimate.analysis import ablation
from trainclimate.analysis.ablation import STEPS, ablate, ablation_markdown
from trainclimate.analysis.experiment import (
    ACTIVATED,
    COOLING_MIN_OFF_S,
    DEACTIVATED,
    EDGE,
    EXPERIMENTS,
)
from trainclimate.analysis.kpi import avg_hourly_violation_k
from trainclimate.cli import main
from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.coach.states import COOLING
from trainclimate.sim import scenarios


@pytest.fixture(scope="module")
def october(record_pair):
    """parked-cooling-oct as the paper ran it: 11:00–20:00, the layer on at 13:15, counted from
    14:00; both connection losses and the cooling's switching limit; the paper's objective."""
    return record_pair("parked-cooling-oct", objective="paper")


@pytest.fixture(scope="module")
def october_ambient_only(record_pair):
    """The same without the room's say in the HVAC state (the state logic before)."""
    setup = EXPERIMENTS["parked-cooling-oct"]
    return record_pair(
        "parked-cooling-oct",
        setup=dataclasses.replace(setup, hvac_options={"climate_from_room": 0.0}),
        objective="paper",
    )


def windows_local(comparison) -> list[str]:
    return [f"{t.tz_convert(scenarios.LOCAL_TZ):%H:%M}" for t in comparison.window_start]


# --- the meters ----------------------------------------------------------------------------------
def test_the_hvac_meter_saves_more_when_the_setpoint_does_not_move_the_floor_heating(heating_3h):
    """Heating in November: the floor and wall heating follows the state and T_amb, not T_ref,
    so it is the same in both coaches and only dilutes the whole-coach saving."""
    pair = heating_3h.pair
    result, (hvac, _) = pair.result, pair.by_meter["hvac"]
    whole, _ = pair.by_meter["hvac_and_floor"]
    floor = result.power_w["floor_wall"]
    np.testing.assert_allclose(floor[:, ACTIVATED], floor[:, DEACTIVATED], rtol=0, atol=1e-9)
    floor_kwh = whole.energy_deactivated_total_kwh - hvac.energy_deactivated_total_kwh
    assert floor_kwh > 1.0  # a parked coach at 0–4 °C heats its floor: kWh over the 1.5 h
    assert whole.energy_activated_total_kwh - hvac.energy_activated_total_kwh == pytest.approx(
        floor_kwh, rel=1e-9
    )
    assert hvac.savings_pct > whole.savings_pct > 0
    # the saved kWh are the same; only the denominator grows by the floor heating
    saved = hvac.energy_deactivated_total_kwh * hvac.savings_pct
    assert whole.energy_deactivated_total_kwh * whole.savings_pct == pytest.approx(saved, rel=1e-9)
    data = pair.to_dict()
    assert data["meter"] == "hvac" and data["savings_pct"] == hvac.savings_pct
    assert data["savings_by_meter_pct"] == {
        "hvac": hvac.savings_pct,
        "hvac_and_floor": whole.savings_pct,
    }
    assert set(data["edge_savings_by_meter_pct"]) == {"hvac", "hvac_and_floor"}
    assert data["edge_savings_pct"] == data["edge_savings_by_meter_pct"]["hvac"]


# --- the October experiment ----------------------------------------------------------------------
def test_the_october_coaches_are_cooling_most_of_the_counted_time(october, october_ambient_only):
    share = october.pair.state_share
    cooling = share["deactivated"].get("cooling", 0.0)
    assert cooling > 0.5, share
    assert sum(share["deactivated"].values()) == pytest.approx(1.0)
    # the activated coach, its setpoint towards the upper bound, cools too or floats (mixed)
    assert share["activated"].get("heating", 0.0) < 0.35, share
    # with the ambient alone deciding, the coaches were mixed all afternoon
    before = october_ambient_only.pair.state_share["deactivated"]
    assert before.get("mixed", 0.0) > 0.8 and before.get("cooling", 0.0) == 0.0, before


def test_the_state_share_counts_the_included_windows_only(october):
    pair = october.pair
    c = pair.comparison
    states = pair.result.hvac_state[:, DEACTIVATED]
    counted = np.zeros(len(pair.result.time), bool)
    for start, excluded in zip(c.window_start, c.excluded, strict=True):
        if not excluded:
            counted |= (pair.result.time >= start) & (
                pair.result.time < start + pd.Timedelta(minutes=30)
            )
    assert counted.sum() == 30 * 6 * int((~c.excluded).sum())
    expected = np.mean(states[counted] == COOLING)
    assert pair.state_share["deactivated"]["cooling"] == pytest.approx(expected, rel=1e-12)


# --- the field events ----------------------------------------------------------------------------
def test_experiment_1_excludes_both_connection_losses(october):
    """Counted from 14:00: the deactivated coach's loss 13:45–14:15 excludes 14:00–14:30, the
    activated coach's from 17:50 every window from 17:30 on."""
    pair = october.pair
    c = pair.comparison
    assert windows_local(c) == [f"{h:02d}:{m:02d}" for h in range(14, 20) for m in (0, 30)]
    excluded = [w for w, x in zip(windows_local(c), c.excluded, strict=True) if x]
    assert excluded == ["14:00", "17:30", "18:00", "18:30", "19:00", "19:30"]
    result = pair.result
    lost_deact = (result.time >= scenarios.local_clock(result.time[0], "13:45")) & (
        result.time < scenarios.local_clock(result.time[0], "14:15")
    )
    np.testing.assert_array_equal(pair.affected[:, DEACTIVATED], lost_deact)
    assert pair.affected[:, ACTIVATED].sum() == (20 * 60 - (17 * 60 + 50)) * 6
    assert np.array_equal(pair.affected[:, EDGE], pair.affected[:, ACTIVATED])
    for meter, (act, edge) in pair.by_meter.items():
        assert act.excluded.tolist() == c.excluded.tolist() == edge.excluded.tolist(), meter


def test_experiment_3_excludes_everything_after_its_connection_loss(record_pair):
    run = record_pair("parked-cooling-aug-energy")
    c = run.pair.comparison
    windows = windows_local(c)
    assert windows[0] == "10:45" and windows[-1] == "18:15"  # counted from the lead-in + 45 min
    excluded = [w for w, x in zip(windows, c.excluded, strict=True) if x]
    assert excluded == windows[windows.index("15:15") :]
    assert c.excluded_minutes == 30.0 * len(excluded)


def test_the_cooling_switching_limit_holds_in_experiment_1(october):
    """No deck's cooling restarts within COOLING_MIN_OFF_S of stopping, in either coach."""
    result = october.pair.result
    steps = int(COOLING_MIN_OFF_S / result.dt_s)
    assert october.params[ACTIVATED].cooling_min_off_s == COOLING_MIN_OFF_S
    restarts = 0
    for coach in (ACTIVATED, DEACTIVATED):
        cooling = result.q_hvac_w[:, coach, :] < 0
        for deck in range(3):
            on = cooling[:, deck]
            stops = np.flatnonzero(on[:-1] & ~on[1:]) + 1
            starts = np.flatnonzero(~on[:-1] & on[1:]) + 1
            for stop in stops:
                later = starts[starts > stop]
                if len(later):
                    restarts += 1
                    assert later[0] - stop >= steps
    assert restarts > 0  # the limit was exercised


# --- violation from the sensors ------------------------------------------------------------------
def test_the_violation_from_the_sensors_is_the_same_maths_on_their_readings(october):
    pair = october.pair
    result, c = pair.result, pair.comparison
    mask = np.zeros(len(result.time), bool)
    for start in c.window_start:  # violation counts every window's samples but the affected
        mask |= (result.time >= start) & (result.time < start + pd.Timedelta(minutes=30))
    mask &= ~pair.affected[:, ACTIVATED] & ~pair.affected[:, DEACTIVATED]
    mask &= result.env.mode[: len(result.time), ACTIVATED] == MODE_REGULAR
    sensed = avg_hourly_violation_k(
        result.t_room_meas_c[:, ACTIVATED],
        result.t_rule_c[:, ACTIVATED],
        result.dt_s,
        mask=mask,
    )
    assert pair.violation_sensor_k == pytest.approx(sensed, rel=1e-9)
    true = pair.comparison.avg_hourly_violation_k
    assert pair.to_dict()["avg_hourly_violation_sensor_k"] == pair.violation_sensor_k
    assert pair.violation_sensor_k != true  # noise and the 0.1-K resolution move it


# --- the ablation --------------------------------------------------------------------------------
def test_the_ablation_adds_the_conditions_in_order(small_predictor, october, october_ambient_only):
    row = ablate("parked-cooling-oct", small_predictor)
    steps = row["steps"]
    assert list(steps) == list(STEPS)
    first = october_ambient_only.pair  # the earlier events differ: only its savings are compared
    full = october.pair
    assert steps["field_events"]["savings_pct"] == pytest.approx(full.comparison.savings_pct)
    assert steps["sensor_violation"]["avg_hourly_violation_k"] == pytest.approx(
        full.violation_sensor_k
    )
    assert steps["field_events"]["avg_hourly_violation_k"] == pytest.approx(
        full.comparison.avg_hourly_violation_k
    )
    # the first two steps are one run, on its two meters
    assert (
        steps["before"]["deactivated_cooling_share"]
        == steps["hvac_meter"]["deactivated_cooling_share"]
    )
    assert steps["before"]["deactivated_cooling_share"] == 0.0
    assert steps["october"]["deactivated_cooling_share"] > 0.5
    assert first.state_share["deactivated"].get("cooling", 0.0) == 0.0
    assert row["paper"] == {"savings_pct": 28.03, "violation_k": 0.0173}
    table = ablation_markdown([row])
    assert table.splitlines()[0].startswith("| experiment | as before | + HVAC meter |")
    assert "| parked-cooling-oct |" in table and "28.03; 0.0173 K" in table


def test_experiment_summary_ablation_writes_the_table(
    capsys, small_predictor_file, tmp_path, monkeypatch
):
    monkeypatch.setattr(
        ablation, "EXPERIMENTS", {"parked-heating-nov": EXPERIMENTS["parked-heating-nov"]}
    )
    argv = ["experiment", "summary", "--ablation", "--predictor", str(small_predictor_file)]
    assert main([*argv, "--out", str(tmp_path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["steps"] == list(STEPS)
    (row,) = data["experiments"]
    assert row["scenario"] == "parked-heating-nov" and set(row["steps"]) == set(STEPS)
    # November heats: the meter step raises the saving, the state logic leaves it alone
    steps = row["steps"]
    assert steps["hvac_meter"]["savings_pct"] > steps["before"]["savings_pct"]
    assert (tmp_path / "ablation.md").read_text(encoding="utf-8") == ablation_markdown([row])


def test_the_ablation_reproduces_the_papers_formulation_only(capsys, tmp_path):
    argv = ["experiment", "summary", "--ablation", "--objective", "margin"]
    assert main([*argv, "--out", str(tmp_path)]) != 0
    err = capsys.readouterr().err
    assert "--ablation reproduces the paper's formulation: --objective paper" in err
    assert not list(tmp_path.iterdir())
