"""The pipeline of Section III.A: each defect handled and counted, fusion by hand, segmentation,
fidelity on a clean simulated day, and the dataset build's handling of bad files."""

import json
import logging

import numpy as np
import pandas as pd
import pytest

from trainclimate.data import fleetlogs
from trainclimate.data.dataset import build_dataset
from trainclimate.data.formats import CANONICAL, WINTER_FORMAT, log_path, to_export, write_export
from trainclimate.data.pipeline import (
    SIGNALS,
    Counts,
    PipelineError,
    PipelineSettings,
    aggregate,
    clean,
    fuse,
    process_coach_day,
)
from trainclimate.data.trajectory import Y_NAMES, read_trajectories

T0 = pd.Timestamp("2022-03-01 06:00", tz="UTC")
#: the coach-day of 2022-03-01: 03:00 CET to 03:00 CET
START, END = pd.Timestamp("2022-03-01 02:00", tz="UTC"), pd.Timestamp("2022-03-02 02:00", tz="UTC")
META = {"campaign": "winter-spring", "train": "44", "coach": "44A"}
SETTINGS = PipelineSettings()


def minute(hhmm: str) -> pd.Timestamp:
    return pd.Timestamp(f"2022-03-01 {hhmm}", tz="UTC")


def hvac_log(minutes=120, *, start=T0, step_s=60, mode="regular", t_ref=22.0, speed=0.0):
    """A canonical HVAC log; each deck warms by 0.01 K per sample (so interpolation is exact)."""
    n = int(minutes * 60 // step_s)
    k = np.arange(n)
    return pd.DataFrame(
        {
            "time": start + pd.to_timedelta(k * step_s, unit="s"),
            "mode": mode,
            "t_ref_c": t_ref,
            "t_room_up_c": 21.0 + 0.01 * k,
            "t_room_mid_c": 21.5 + 0.01 * k,
            "t_room_low_c": 20.5 + 0.01 * k,
            "speed_kmh": speed,
        }
    )


def weather_log(start=None, hours=4, step_min=10, **values):
    """A canonical weather log from ``start`` (default 05:00) of a train standing at Zurich HB at
    night (T_amb rising 0.1 K per sample unless given)."""
    start = minute("05:00") if start is None else start
    n = int(hours * 60 // step_min) + 1
    frame = pd.DataFrame(
        {
            "time": start + pd.to_timedelta(np.arange(n) * step_min, unit="min"),
            "latitude_deg": 47.3779,
            "longitude_deg": 8.5403,
            "t_amb_c": 2.0 + 0.1 * np.arange(n),
            "ghi_w_m2": 0.0,
            "solar_elevation_deg": -20.0,
            "solar_azimuth_deg": 90.0,
        }
    )
    for col, value in values.items():
        frame[col] = value
    return frame


def trips_log(*trips):
    """Trips as (departure, arrival, occupancy %)."""
    rows = [("44", minute(a), minute(b), "Zürich HB", "Winterthur", occ) for a, b, occ in trips]
    frame = pd.DataFrame(rows, columns=list(CANONICAL["trips"]))
    for col in ("departure", "arrival"):
        frame[col] = pd.to_datetime(frame[col], utc=True)
    return frame


def run(hvac, weather=None, trips=None, **settings):
    sources = {
        "hvac": hvac,
        "weather": weather_log() if weather is None else weather,
        "trips": trips_log() if trips is None else trips,
    }
    return process_coach_day(
        sources, start=START, end=END, meta=META, settings=PipelineSettings(**settings)
    )


def spans(trajectories):
    return [(t.time[0], t.time[-1], len(t)) for t in trajectories]


def nonzero(counter):
    return {k: v for k, v in counter.items() if v}


# --- 0. clean: one test per defect -----------------------------------------------------------
def test_out_of_order_rows_are_sorted_back_and_counted_as_repaired():
    log = hvac_log(60)
    shuffled = pd.concat([log.iloc[:10], log.iloc[13:40], log.iloc[10:13], log.iloc[40:]])
    counts = Counts()
    cleaned = clean(shuffled, "hvac", counts, SETTINGS)
    pd.testing.assert_frame_equal(cleaned, log)
    assert nonzero(counts.repaired) == {"out_of_order": 3}
    assert nonzero(counts.dropped) == {}


def test_duplicated_rows_are_dropped_and_counted():
    log = hvac_log(60)
    doubled = pd.concat(
        [log.iloc[:6], log.iloc[[5]], log.iloc[6:21], log.iloc[[20]], log.iloc[21:]]
    )
    counts = Counts()
    cleaned = clean(doubled, "hvac", counts, SETTINGS)
    pd.testing.assert_frame_equal(cleaned, log)
    assert nonzero(counts.dropped) == {"duplicate": 2}
    assert nonzero(counts.repaired) == {}


def cells(counts, source):
    return {k: v for k, v in counts.cells[source].items() if v}


def test_an_empty_cell_invalidates_that_signal_and_a_row_with_none_left_is_dropped():
    log = hvac_log(60)
    log.loc[7, "t_room_mid_c"] = np.nan
    log.loc[9, "mode"] = None
    log.loc[11, "speed_kmh"] = np.nan
    log.loc[13, ["mode", "t_ref_c", *Y_NAMES, "speed_kmh"]] = np.nan  # nothing but a time
    counts = Counts()
    cleaned = clean(log, "hvac", counts, SETTINGS)
    assert nonzero(counts.dropped) == {"no_valid_value": 1}
    assert len(cleaned) == 59 and not cleaned["time"].isin(log["time"][[13]]).any()
    # the other readings of rows 7, 9 and 11 are kept as they were
    pd.testing.assert_frame_equal(cleaned, log.drop(index=13).reset_index(drop=True))


def test_fault_codes_and_impossible_values_invalidate_their_cells():
    log = hvac_log(60)
    log.loc[3, "t_room_up_c"] = 85.0
    log.loc[4, "t_room_low_c"] = -40.0
    log.loc[5, "t_ref_c"] = 85.0
    log.loc[6, "speed_kmh"] = -1.0
    counts = Counts()
    cleaned = clean(log, "hvac", counts, SETTINGS)
    assert nonzero(counts.dropped) == {}
    assert cells(counts, "hvac") == {
        (c, "out_of_range"): 1 for c in ("t_room_up_c", "t_room_low_c", "t_ref_c", "speed_kmh")
    }
    assert len(cleaned) == 60 and int(cleaned.isna().sum().sum()) == 4
    assert cleaned.loc[3, "t_room_mid_c"] == log.loc[3, "t_room_mid_c"]

    weather = weather_log()
    weather.loc[2, "ghi_w_m2"] = -5.5  # beyond a night offset (OFFSET_TOLERANCE)
    weather.loc[3, "latitude_deg"] = 95.0
    trips = trips_log(("06:00", "06:30", 20.0), ("07:00", "06:50", 30.0), ("07:10", "07:40", 400.0))
    counts = Counts()
    assert len(clean(weather, "weather", counts, SETTINGS)) == len(weather)
    cleaned_trips = clean(trips, "trips", counts, SETTINGS)
    # a trip ending before it starts is no trip; an impossible occupancy is an unknown one
    assert len(cleaned_trips) == 2 and np.isnan(cleaned_trips["occupancy_pct"].iloc[1])
    assert nonzero(counts.dropped) == {"out_of_range": 1}
    assert cells(counts, "weather") == {
        ("ghi_w_m2", "out_of_range"): 1,
        ("latitude_deg", "out_of_range"): 1,
    }
    assert cells(counts, "trips") == {("occupancy_pct", "out_of_range"): 1}


def test_a_jump_in_one_sample_is_a_spike_but_a_genuine_setpoint_step_is_kept():
    log = hvac_log(60)
    log.loc[30:, "t_ref_c"] = 24.0  # the driver raises the setpoint by 2 K
    log.loc[12, "t_room_mid_c"] += 10.0  # a sensor spike
    counts = Counts()
    cleaned = clean(log, "hvac", counts, SETTINGS)
    assert nonzero(counts.dropped) == {}
    assert cells(counts, "hvac") == {("t_room_mid_c", "spike"): 1}
    expected = log.copy()
    expected.loc[12, "t_room_mid_c"] = np.nan
    pd.testing.assert_frame_equal(cleaned, expected)
    assert (cleaned["t_ref_c"] == 24.0).sum() == 30


def test_spikes_in_the_ten_minute_winter_weather_are_found():
    weather = weather_log(hours=4, step_min=10)
    weather.loc[10, "t_amb_c"] += 10.0
    weather.loc[20, "t_amb_c"] = -40.0  # the −40 fault code: a valid T_amb, but far off
    counts = Counts()
    cleaned = clean(weather, "weather", counts, SETTINGS)
    assert cells(counts, "weather") == {("t_amb_c", "spike"): 2}
    assert len(cleaned) == len(weather) and cleaned["t_amb_c"].isna().sum() == 2
    assert cleaned["t_amb_c"].dropna().between(2.0, 4.5).all()


def test_a_moving_train_without_a_trip_has_unknown_occupancy():
    log = hvac_log(120)
    log.loc[:89, "speed_kmh"] = 60.0  # moving until 07:29, then standing
    trajectories, counts = run(log, trips=trips_log(("06:00", "07:00", 40.0)))
    assert nonzero(counts.dropped) == {"moving_without_trip_rows": 30}
    assert spans(trajectories[1]) == [
        (minute("06:00"), minute("06:59"), 60),
        (minute("07:30"), minute("07:59"), 30),
    ]
    occupancy = [t.d[:, 3] for t in trajectories[1]]
    assert np.all(occupancy[0] == 40.0) and np.all(occupancy[1] == 0.0)


# --- 1. fuse: heading and solar projections by hand ------------------------------------------
@pytest.mark.parametrize(
    ("direction", "step", "heading", "q_gs"),
    [
        ("east", (0.0, 0.01), 90.0, 800 * np.sin(np.radians(60))),  # sun abeam: 692.8
        ("north", (0.01, 0.0), 0.0, 0.0),  # sun straight behind
        ("west", (0.0, -0.01), 270.0, 800 * np.sin(np.radians(60))),
        ("south", (-0.01, 0.0), 180.0, 0.0),  # sun straight ahead
    ],
)
def test_heading_and_solar_projections_by_hand(direction, step, heading, q_gs):
    start = minute("11:00")
    hvac = hvac_log(10, start=start, speed=80.0)
    k = np.arange(3)
    weather = pd.DataFrame(
        {
            "time": start + pd.to_timedelta(k * 5, unit="min"),
            "latitude_deg": 47.0 + step[0] * k,
            "longitude_deg": 8.0 + step[1] * k,
            "t_amb_c": [10.0, 15.0, 20.0],
            "ghi_w_m2": 800.0,
            "solar_elevation_deg": 30.0,  # z = 60°
            "solar_azimuth_deg": 180.0,
        }
    )
    fused = fuse(hvac, weather, trips_log(("10:50", "12:00", 55.0)), SETTINGS)
    assert len(fused) == 10
    np.testing.assert_allclose(fused["q_gt_w_m2"], 400.0, rtol=1e-12)  # |800 cos 60°|
    np.testing.assert_allclose(fused["q_gs_w_m2"], q_gs, rtol=1e-6, atol=1e-6)
    # T_amb interpolated between the 5-minute weather samples
    np.testing.assert_allclose(fused["t_amb_c"], 10.0 + np.arange(10), rtol=1e-12)
    np.testing.assert_array_equal(fused["occupancy_pct"], 55.0)
    np.testing.assert_array_equal(fused["speed_kmh"], 80.0)


def test_no_sun_no_solar_gain_and_no_weather_across_a_long_gap():
    start = minute("11:00")
    hvac = hvac_log(70, start=start)
    times = start + pd.to_timedelta([0, 10, 60, 70], unit="min")  # a 50-min gap in the weather
    weather = weather_log().iloc[:4].assign(
        time=times, t_amb_c=[1.0, 2.0, 7.0, 8.0], ghi_w_m2=[50.0, 50.0, 0.0, 0.0],
        solar_elevation_deg=[-2.0, -1.0, -0.5, -0.4],
    )  # fmt: skip
    fused = fuse(hvac, weather, trips_log(), SETTINGS).set_index("time")
    t_amb = fused["t_amb_c"]
    assert t_amb[start] == 1.0 and t_amb[minute("11:05")] == pytest.approx(1.5)
    assert t_amb[minute("11:10")] == 2.0 and t_amb[minute("12:00")] == 7.0
    assert t_amb[minute("11:11") : minute("11:59")].isna().all()
    assert (fused.loc[minute("11:00") : minute("11:10"), ["q_gt_w_m2", "q_gs_w_m2"]] == 0).all(
        axis=None
    )


def test_each_weather_signal_is_interpolated_from_its_own_valid_samples():
    start = minute("11:00")
    hvac = hvac_log(30, start=start)
    weather = weather_log(start=start, hours=0.5, step_min=10, ghi_w_m2=100.0,
                          solar_elevation_deg=30.0)  # fmt: skip
    weather.loc[1, "t_amb_c"] = np.nan  # an invalid T_amb at 11:10
    weather.loc[2, "latitude_deg"] = np.nan  # no position at 11:20
    fused = fuse(hvac, weather, trips_log(), SETTINGS).set_index("time")
    # T_amb across its missing sample, from 11:00 and 11:20; the irradiance untouched
    assert fused.loc[minute("11:10"), "t_amb_c"] == pytest.approx(2.1)
    assert fused["t_amb_c"].notna().all() and fused["q_gt_w_m2"].notna().all()
    np.testing.assert_allclose(fused["q_gt_w_m2"], 50.0, rtol=1e-12)  # |100 cos 60°|
    assert fused["q_gs_w_m2"].notna().all()  # the heading from the other positions


# --- 2. aggregate ----------------------------------------------------------------------------
def fused_samples(n, step_s=20):
    """A fused table of ``n`` samples ``step_s`` apart; every signal equals its sample index."""
    times = T0 + pd.to_timedelta(np.arange(n) * step_s, unit="s")
    frame = pd.DataFrame({"time": times, "mode": "regular"})
    for col in SIGNALS:
        frame[col] = np.arange(n, dtype=float)
    return frame


def test_minutes_hold_y_measured_by_t_and_u_d_acting_from_t():
    fused = fused_samples(9)  # 06:00:00 … 06:02:40, three samples a minute
    minutes = aggregate(fused, T0, T0 + pd.Timedelta("3min"))
    # y(t): mean of the samples in (t − 1 min, t]; u, d: mean over [t, t + 1 min)
    assert minutes["t_room_up_c"].tolist()[:3] == [0.0, 2.0, 5.0]
    assert minutes["t_ref_c"].tolist() == [1.0, 4.0, 7.0]
    assert minutes["speed_kmh"].tolist() == [1.0, 4.0, 7.0]
    assert minutes["regular"].tolist() == [1.0, 1.0, 1.0]


def test_a_minute_is_regular_only_if_every_sample_is():
    fused = fused_samples(9)
    fused.loc[4, "mode"] = "slumber"  # 06:01:20
    fused.loc[8, "mode"] = "off"  # 06:02:40
    minutes = aggregate(fused, T0, T0 + pd.Timedelta("4min"))
    np.testing.assert_array_equal(minutes["regular"], [1.0, 0.0, 0.0, np.nan])


def test_a_missing_value_is_left_out_of_the_minute_not_counted_as_zero():
    fused = fused_samples(9)
    fused.loc[4, ["t_ref_c", "speed_kmh", "t_room_up_c"]] = np.nan  # 06:01:20
    fused.loc[7, "mode"] = np.nan  # 06:02:20: a mode label that could not be read
    minutes = aggregate(fused, T0, T0 + pd.Timedelta("3min"))
    assert minutes["t_ref_c"].tolist() == [1.0, 4.0, 7.0]  # (3 + 5) / 2, not (3 + 0 + 5) / 3
    assert minutes["speed_kmh"].tolist() == [1.0, 4.0, 7.0]
    assert minutes["t_room_up_c"].tolist()[:3] == [0.0, 2.0, 5.5]  # (t − 1, t]: 3, (4), 5
    # a minute with a sample of unknown mode is not known to be regular
    np.testing.assert_array_equal(minutes["regular"], [1.0, 1.0, np.nan])


# --- 3. segment: gaps and modes --------------------------------------------------------------
def test_a_long_gap_splits_the_trajectory_at_exactly_its_edges():
    log = hvac_log(120)
    gap = log["time"].between(minute("07:00"), minute("07:09"))
    trajectories, counts = run(log.loc[~gap])
    assert spans(trajectories[1]) == [
        (minute("06:00"), minute("06:59"), 60),
        (minute("07:10"), minute("07:59"), 50),
    ]
    assert nonzero(counts.repaired) == {} and nonzero(counts.dropped) == {}
    # 5-min blocks stop before the gap and resume after it, aligned to the clock
    assert spans(trajectories[5]) == [
        (minute("06:00"), minute("06:55"), 12),
        (minute("07:10"), minute("07:55"), 10),
    ]


@pytest.mark.parametrize("gap_min", [1, 2])
def test_a_short_gap_is_interpolated_and_does_not_split(gap_min):
    log = hvac_log(120)
    gap = log["time"].between(minute("07:00"), minute("07:00") + pd.Timedelta(gap_min - 1, "min"))
    trajectories, counts = run(log.loc[~gap])
    assert nonzero(counts.repaired) == {"short_gap_minutes": gap_min}
    [trajectory] = trajectories[1]
    assert (trajectory.time[0], trajectory.time[-1], len(trajectory)) == (
        minute("06:00"),
        minute("07:59"),
        120,
    )
    # the decks warm linearly, so the interpolated minutes are the missing readings
    np.testing.assert_allclose(trajectory.y, log[list(Y_NAMES)].to_numpy(), atol=1e-9)


def test_a_gap_one_minute_longer_than_max_fill_splits():
    log = hvac_log(120)
    gap = log["time"].between(minute("07:00"), minute("07:02"))
    trajectories, counts = run(log.loc[~gap])
    assert nonzero(counts.repaired) == {}
    assert [s[:2] for s in spans(trajectories[1])] == [
        (minute("06:00"), minute("06:59")),
        (minute("07:03"), minute("07:59")),
    ]


def test_only_regular_mode_is_kept():
    log = hvac_log(180)
    modes = np.array(["regular"] * 180, dtype=object)
    modes[60:80] = "slumber"  # 07:00–07:19, a layover
    modes[150:160] = "off"  # 08:30–08:39
    modes[100] = "slumber"  # one minute is enough to end a trajectory (no gap filling)
    log["mode"] = modes
    trajectories, counts = run(log)
    assert spans(trajectories[1]) == [
        (minute("06:00"), minute("06:59"), 60),
        (minute("07:41"), minute("08:29"), 49),
    ]
    # 07:20–07:39 and 08:40–08:59 are regular but shorter than 30 min
    assert nonzero(counts.dropped) == {"too_short_minutes": 40}
    assert nonzero(counts.repaired) == {}
    not_regular = set(log.loc[log["mode"] != "regular", "time"])
    for step, found in trajectories.items():
        for t in found:
            covered = {s + pd.Timedelta(minutes=m) for s in t.time for m in range(step)}
            assert not covered & not_regular
    assert spans(trajectories[5]) == [
        (minute("06:00"), minute("06:55"), 12),
        (minute("07:45"), minute("08:25"), 9),
    ]
    # the second piece holds only four 10-min blocks (07:50–08:29), fewer than min_points
    assert spans(trajectories[10]) == [(minute("06:00"), minute("06:50"), 6)]


# --- a clean simulated day comes back unchanged ----------------------------------------------
@pytest.fixture(scope="module")
def clean_day():
    """One winter in-service coach-day simulated and logged without defects, then processed."""
    campaign = fleetlogs.WINTER_SPRING
    plan = fleetlogs.plan_day(campaign, 1, 0, fleetlogs.Defects.none())
    assert plan.logged and plan.in_service
    result, ops, params = fleetlogs.simulate_coach_days(
        [plan], fleetlogs.campaign_weather(campaign), fleetlogs.fleet_params()
    )
    logs = fleetlogs.coach_day_logs(
        plan, 0, result, ops[0], params[0], np.random.default_rng([plan.seed, 1])
    )
    trajectories, counts = process_coach_day(
        logs, start=plan.start, end=plan.end, meta={"campaign": campaign.name}
    )
    grid = pd.date_range(plan.start, periods=len(result.env.time), freq="10s")
    truth = pd.DataFrame(result.states_c[:, 0, :3], index=grid, columns=list(Y_NAMES))
    truth["t_amb_c"] = result.env.t_amb_c[:, 0]
    return logs, trajectories, counts, truth


def test_a_clean_day_loses_no_row_and_keeps_every_regular_minute(clean_day):
    logs, trajectories, counts, _ = clean_day
    assert nonzero(counts.dropped) == {} and nonzero(counts.repaired) == {}
    regular = logs["hvac"]["mode"] == "regular"
    assert sum(len(t) for t in trajectories[1]) == regular.sum() > 600
    assert len(trajectories[1]) == len(trajectories[5]) == len(trajectories[10]) >= 1


def test_a_clean_day_comes_back_unchanged_to_the_sensors_quantisation(clean_day):
    logs, trajectories, _, truth = clean_day
    hvac = logs["hvac"].set_index("time")
    errors = []
    for t in trajectories[1]:
        # winter logs one instantaneous sample a minute: y(t) and u(t) are the readings at t
        np.testing.assert_array_equal(t.y, hvac.loc[t.time, list(Y_NAMES)].to_numpy())
        np.testing.assert_array_equal(t.u[:, 0], hvac.loc[t.time, "t_ref_c"].to_numpy())
        np.testing.assert_array_equal(t.d[:, 4], hvac.loc[t.time, "speed_kmh"].to_numpy())
        np.testing.assert_allclose(t.d[:, 0], truth.loc[t.time, "t_amb_c"], atol=1e-9)
        errors.append(t.y - truth.loc[t.time, list(Y_NAMES)].to_numpy())
    errors = np.concatenate(errors)
    # Sensor model: N(0, 0.05 K) noise, then 0.1 K quantisation, so the error has σ ≈ 0.058 K
    # and a mean absolute value ≈ 0.046 K (measured: 0.046 K mean, 0.25 K max over 3 × 1085
    # readings, bias < 0.004 K). Bounds: a 30 % margin on the mean, ≈ 5σ on the maximum, and
    # ≈ 5 standard errors on the bias — a pipeline shifting y by one minute or one quantum fails.
    assert np.abs(errors).mean() <= 0.06
    assert np.abs(errors).max() <= 0.3
    assert np.all(np.abs(errors.mean(axis=0)) <= 0.01)


@pytest.mark.parametrize("step", [5, 10])
def test_downsampling_takes_y_at_the_block_start_and_means_of_u_and_d(clean_day, step):
    _, trajectories, _, _ = clean_day
    for coarse, fine in zip(trajectories[step], trajectories[1], strict=True):
        assert coarse.sampling_min == step
        assert all(t.minute % step == 0 for t in coarse.time)
        assert np.all(np.diff(coarse.time) == pd.Timedelta(minutes=step))
        start = fine.time.get_loc(coarse.time[0])
        assert len(fine) - start - step < step * len(coarse) <= len(fine) - start
        blocks = slice(start, start + step * len(coarse))
        np.testing.assert_array_equal(coarse.y, fine.y[blocks][::step])
        np.testing.assert_allclose(
            coarse.u, fine.u[blocks].reshape(len(coarse), step, 1).mean(axis=1), rtol=1e-12
        )
        np.testing.assert_allclose(
            coarse.d, fine.d[blocks].reshape(len(coarse), step, 5).mean(axis=1), rtol=1e-12
        )


# --- the dataset build: bad files never crash it ---------------------------------------------
def write_coach_day(raw, train, coach, hvac_rows=None):
    """Winter-format logs of one coach-day (2022-03-01) standing in regular mode 06:00–08:00 UTC;
    ``hvac_rows`` edits the exported HVAC rows (a list of lists of strings)."""
    day = "2022-03-01"
    hvac = to_export(hvac_log(120), "hvac", WINTER_FORMAT)
    lines = [list(row) for row in hvac.itertuples(index=False)]
    if hvac_rows:
        lines = hvac_rows(lines)
    path = log_path(raw, "winter-spring", "hvac", train, coach, day)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        "\n".join([";".join(WINTER_FORMAT.header["hvac"]), *(";".join(r) for r in lines)]) + "\n",
        encoding="utf-8",
    )
    for source, table in (("weather", weather_log()), ("trips", trips_log())):
        exported = to_export(table, source, WINTER_FORMAT)
        write_export(exported, log_path(raw, "winter-spring", source, train, coach, day),
                     WINTER_FORMAT)  # fmt: skip
    return path


def with_defects(rows):
    rows = [list(r) for r in rows]
    rows[10][3] = "85,00"  # fault code → an out_of_range cell
    rows[20][4] = ""  # empty field → a missing cell
    rows[30][5] = str(float(rows[30][5].replace(",", ".")) + 10).replace(".", ",")  # spike
    rows = [*rows[:40], rows[40], *rows[40:]]  # duplicate
    rows = [*rows[:50], *rows[55:70], *rows[50:55], *rows[70:]]  # 5 rows out of order
    return [*rows[:60], ["### logger restart ###", "", "", "", "", "", ""], *rows[60:]]


def test_every_defect_in_a_raw_directory_is_counted_by_reason(tmp_path):
    write_coach_day(tmp_path / "raw", "44", "44A", with_defects)
    summary = build_dataset(tmp_path / "raw", tmp_path / "out")
    assert nonzero(summary.dropped_rows) == {"duplicate": 1, "unparseable": 1}
    assert summary.invalid_cells == {"missing": 1, "out_of_range": 1, "spike": 1}
    assert summary.rows["hvac"]["invalid_cells"] == {
        "t_room_up_c": {"out_of_range": 1},
        "t_room_mid_c": {"missing": 1},
        "t_room_low_c": {"spike": 1},
    }
    # the three invalid cells leave one-minute holes in their signal, interpolated
    assert nonzero(summary.repaired_rows) == {"out_of_order": 5, "short_gap_minutes": 3}
    assert summary.raw_rows == 122 + len(weather_log())  # with the garbage line and the copy
    [trajectory] = read_trajectories(tmp_path / "out" / "trajectories_1min.parquet")
    assert (trajectory.time[0], len(trajectory)) == (minute("06:00"), 120)
    np.testing.assert_allclose(trajectory.y, hvac_log(120)[list(Y_NAMES)], atol=1e-9)


def bad_cells(rows):
    rows = [list(r) for r in rows]
    rows[15][6] = "0,0x"  # a speed that cannot be read
    rows[25][1] = "Turbo"  # a mode label that is none of the format's
    rows[35][2] = "85,00"  # a setpoint fault code
    rows[45][4] = ""  # no middle-deck reading
    return rows


def test_a_bad_cell_invalidates_its_signal_and_changes_no_other_reading(tmp_path):
    write_coach_day(tmp_path / "clean", "44", "44A")
    write_coach_day(tmp_path / "bad", "44", "44A", bad_cells)
    build_dataset(tmp_path / "clean", tmp_path / "out-clean")
    summary = build_dataset(tmp_path / "bad", tmp_path / "out-bad")
    assert summary.dropped_rows == {} and summary.rows["hvac"]["kept"] == 120
    assert summary.rows["hvac"]["invalid_cells"] == {
        "speed_kmh": {"unparseable": 1},
        "mode": {"unparseable": 1},
        "t_ref_c": {"out_of_range": 1},
        "t_room_mid_c": {"missing": 1},
    }
    [expected] = read_trajectories(tmp_path / "out-clean" / "trajectories_1min.parquet")
    [got] = read_trajectories(tmp_path / "out-bad" / "trajectories_1min.parquet")
    # every minute kept; each hole filled in its own signal only, from its neighbours
    assert (got.time == expected.time).all() and len(got) == 120
    for name in ("y", "u", "d"):
        np.testing.assert_allclose(getattr(got, name), getattr(expected, name), atol=1e-9)
    assert summary.repaired_rows["short_gap_minutes"] == 4


def test_an_unreadable_file_is_named_in_a_warning_and_the_rest_still_processes(tmp_path, caplog):
    raw = tmp_path / "raw"
    write_coach_day(raw, "44", "44A")
    broken = write_coach_day(raw, "66", "66A")
    broken.write_bytes(bytes(np.random.default_rng(7).integers(0, 256, 512, dtype=np.uint8)))
    stray = raw / "notes.csv"
    stray.write_text("not a log\n")
    with caplog.at_level(logging.WARNING, logger="trainclimate.data.dataset"):
        summary = build_dataset(raw, tmp_path / "out")
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(str(broken) in w and "unreadable" in w for w in warnings)
    assert any(str(stray) in w and "skipped" in w for w in warnings)
    assert summary.unreadable_files == [str(broken)]
    assert summary.coach_days == 2
    assert [(r["sampling_min"], r["trajectories"]) for r in summary.table] == [(1, 1), (5, 1),
                                                                              (10, 1)]  # fmt: skip
    [trajectory] = read_trajectories(tmp_path / "out" / "trajectories_1min.parquet")
    assert (trajectory.coach, trajectory.train, trajectory.campaign) == (
        "44A",
        "44",
        META["campaign"],
    )


def test_an_empty_or_unusable_raw_directory_is_a_pipeline_error(tmp_path):
    raw = tmp_path / "raw"
    with pytest.raises(PipelineError, match="not found"):
        build_dataset(raw, tmp_path / "out")
    raw.mkdir()
    with pytest.raises(PipelineError, match="no raw log files"):
        build_dataset(raw, tmp_path / "out")
    garbage = log_path(raw, "winter-spring", "hvac", "44", "44A", "2022-03-01")
    garbage.parent.mkdir(parents=True)
    garbage.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    with pytest.raises(PipelineError, match=r"no usable trajectory .* 1 unreadable file"):
        build_dataset(raw, tmp_path / "out")


def test_a_coach_day_parked_all_day_gives_nothing():
    trajectories, counts = run(hvac_log(120, mode="off"))
    assert trajectories == {1: [], 5: [], 10: []}
    assert nonzero(counts.dropped) == {} and nonzero(counts.repaired) == {}


def test_files_corrupted_on_purpose_are_counted_in_one_line_others_still_warn(tmp_path, caplog):
    raw = tmp_path / "raw"
    write_coach_day(raw, "44", "44A")
    noise = bytes(np.random.default_rng(7).integers(0, 256, 512, dtype=np.uint8))
    generated = [write_coach_day(raw, "66", "66A"), write_coach_day(raw, "17", "17A")]
    users = write_coach_day(raw, "31", "31A")
    for path in (*generated, users):
        path.write_bytes(noise)
    with caplog.at_level(logging.INFO, logger="trainclimate.data.dataset"):
        summary = build_dataset(raw, tmp_path / "out", expected_unreadable=generated)
    messages = [(r.levelno, r.getMessage()) for r in caplog.records]
    assert (logging.INFO, "2 corrupted files skipped, as generated") in messages
    warnings = [m for level, m in messages if level == logging.WARNING]
    assert len(warnings) == 1 and str(users) in warnings[0] and "unreadable" in warnings[0]
    assert sorted(summary.unreadable_files) == sorted(map(str, (*generated, users)))
    assert summary.unreadable_as_generated == 2


def test_a_failed_run_leaves_the_previous_output_whole(tmp_path):
    raw, out = tmp_path / "raw", tmp_path / "out"
    write_coach_day(raw, "44", "44A")
    build_dataset(raw, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert sorted(before) == [
        "dataset.json",
        "trajectories_10min.parquet",
        "trajectories_1min.parquet",
        "trajectories_5min.parquet",
    ]
    # the same directory, now unusable: the run fails and nothing it wrote is left
    for path in raw.rglob("*.csv"):
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    with pytest.raises(PipelineError, match="no usable trajectory"):
        build_dataset(raw, out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_every_raw_file_is_reported(tmp_path):
    raw = tmp_path / "raw"
    write_coach_day(raw, "44", "44A", with_defects)
    broken = write_coach_day(raw, "66", "66A")
    broken.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    summary = build_dataset(raw, tmp_path / "out")
    files = {f["path"]: f for f in summary.files}
    assert len(files) == 6
    hvac = files["winter-spring/hvac/44_44A_2022-03-01.csv"]
    assert (hvac["source"], hvac["encoding"], hvac["delimiter"]) == ("hvac", "utf-8", ";")
    assert (hvac["rows_read"], hvac["rows_kept"], hvac["dropped"]) == (122, 121, {"unparseable": 1})
    assert files["winter-spring/hvac/66_66A_2022-03-01.csv"]["error"].startswith("not text")
    report = json.loads((tmp_path / "out" / "dataset.json").read_text())
    assert (
        report["files"] == summary.files
        and report["outputs"]["1min"] == "trajectories_1min.parquet"
    )


def test_filling_a_short_gap_never_rewrites_a_reading_measured_in_it():
    """A minute where only some signals are missing (here the speed, after one bad cell): the
    fill takes the missing ones from the neighbours and leaves every measured one as it is."""
    from trainclimate.data.pipeline import segment

    times = pd.date_range("2022-03-01 06:00", periods=40, freq="1min", tz="UTC")
    minutes = pd.DataFrame({name: 1.0 for name in SIGNALS}, index=times)
    minutes["regular"] = 1.0
    minutes["speed_kmh"] = 0.0  # standing still
    minutes.iloc[10:12, minutes.columns.get_loc("speed_kmh")] = np.nan  # the bad cells
    minutes.iloc[10:12, minutes.columns.get_loc("regular")] = np.nan  # no full minute
    minutes.iloc[10, minutes.columns.get_loc(Y_NAMES[0])] = 7.0  # measured in the gap …
    minutes.iloc[11, minutes.columns.get_loc(Y_NAMES[0])] = np.nan  # … and missing next to it
    counts = Counts()
    [piece] = segment(minutes, PipelineSettings(), counts)
    assert counts.repaired["short_gap_minutes"] == 2
    assert list(piece["speed_kmh"].iloc[9:13]) == [0.0, 0.0, 0.0, 0.0]
    assert piece[Y_NAMES[0]].iloc[10] == 7.0  # kept, not interpolated to 1.0
    assert piece[Y_NAMES[0]].iloc[11] == 1.0


def test_the_metered_power_is_carried_but_its_gaps_split_nothing():
    log = hvac_log(120)
    log["p_hvac_kw"] = 4.0 + 0.01 * np.arange(120)
    log.loc[30:44, "p_hvac_kw"] = np.nan  # the meter drops out for 15 min
    trajectories, _ = run(log)
    [one] = trajectories[1]
    assert len(one) == 120  # the same trajectory as without a meter
    np.testing.assert_allclose(one.p_kw[:30], 4.0 + 0.01 * np.arange(30))
    assert np.isnan(one.p_kw[30:45]).all()
    [five] = trajectories[5]
    np.testing.assert_allclose(five.p_kw[:6], [4.02 + 0.05 * k for k in range(6)])
    assert np.isnan(five.p_kw[6:9]).all()  # a block with a minute missing has no mean


def test_the_share_of_each_minute_the_train_stood_is_carried():
    log = hvac_log(120, step_s=20)  # three samples a minute
    log.loc[log.index % 3 == 0, "speed_kmh"] = 30.0  # moving for the first 20 s of each minute
    trajectories, _ = run(log, trips=trips_log(("05:00", "09:00", 40.0)))
    [one] = trajectories[1]
    np.testing.assert_allclose(one.standing, 2 / 3)
    np.testing.assert_allclose(one.d[:, 4], 10.0)  # the mean speed says less
