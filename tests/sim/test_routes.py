import numpy as np
import pandas as pd
import pytest

from trainclimate.sim.routes import (
    ACCEL_M_S2,
    LINES,
    bearing_deg,
    haversine_m,
    heading_from_positions,
    service_day,
    stationary,
)


def test_bearing_and_distance():
    assert bearing_deg(47, 8, 48, 8) == pytest.approx(0.0)
    assert bearing_deg(47, 8, 47, 9) == pytest.approx(90.0, abs=0.5)
    assert bearing_deg(48, 8, 47, 8) == pytest.approx(180.0)
    assert bearing_deg(47, 9, 47, 8) == pytest.approx(270.0, abs=0.5)
    assert 19_000 < haversine_m(47.3779, 8.5403, 47.4999, 8.7236) < 21_000


def test_heading_from_positions_holds_while_stopped():
    lat = np.array([47.0, 47.0, 47.001, 47.002, 47.002, 47.002, 47.002])
    lon = np.array([8.0, 8.0, 8.0, 8.0, 8.0, 8.001, 8.002])
    h = heading_from_positions(lat, lon)
    assert h[0] == pytest.approx(0.0) and h[2] == pytest.approx(0.0)
    assert h[3] == pytest.approx(0.0)  # stopped: the last heading holds
    assert h[4] == pytest.approx(90.0, abs=0.5)


def day(step_s=10, seed=3, **kw):
    t = pd.date_range(
        "2022-03-28 03:00", "2022-03-28 23:00", freq=f"{step_s}s", tz="Europe/Zurich"
    ).tz_convert("UTC")
    args = dict(
        seed=seed,
        first_departure=pd.Timestamp("2022-03-28 05:00", tz="Europe/Zurich"),
        last_arrival=pd.Timestamp("2022-03-28 21:00", tz="Europe/Zurich"),
        layovers=[
            (
                pd.Timestamp("2022-03-28 12:00", tz="Europe/Zurich"),
                pd.Timestamp("2022-03-28 13:00", tz="Europe/Zurich"),
            )
        ],
    )
    args.update(kw)
    return service_day(LINES["S8"], t, **args)


@pytest.mark.parametrize("step_s", [10, 60])
def test_service_day_kinematics_and_doors(step_s):
    op = day(step_s)
    line = LINES["S8"]
    assert op.speed_kmh.max() <= line.v_max_kmh + 1e-9
    assert op.speed_kmh.max() > 100
    # doors open only standing in service
    assert np.all(op.speed_kmh[op.doors_open] == 0)
    assert np.all(op.operation[op.doors_open] == "service")
    if step_s == 10:
        accel = np.diff(op.speed_kmh / 3.6) / step_s
        assert accel.max() <= ACCEL_M_S2 + 1e-6
        # every intermediate station: a door opening on each trip (≥ 9 per trip here)
        openings = np.count_nonzero(np.diff(op.doors_open.astype(int)) == 1)
        assert openings >= 9 * 6


def test_operation_phases_and_occupancy():
    op = day()
    local = op.time.tz_convert("Europe/Zurich")
    h = local.hour + local.minute / 60
    assert set(op.operation[h < 4.2]) == {"parked"}
    prep = (h > 4.3) & (h < 5.0)
    assert set(op.operation[prep]) == {"service"} and np.all(op.occupancy_pct[prep] == 0)
    assert set(op.operation[(h > 12.6) & (h < 12.95)]) == {"layover"}
    assert np.all(op.occupancy_pct[op.operation != "service"] == 0)
    assert np.all(op.speed_kmh[op.operation != "service"] == 0)
    assert op.operation[-1] == "parked"
    morning = op.occupancy_pct[(h > 7.2) & (h < 8.3) & (op.speed_kmh > 0)].mean()
    late = op.occupancy_pct[(h > 20.0) & (h < 21.0) & (op.speed_kmh > 0)].mean()
    assert morning > 2 * late
    assert op.occupancy_pct.min() >= 0 and op.occupancy_pct.max() <= 150


def test_run_times_between_stations():
    op = day()
    moving = op.speed_kmh > 0
    starts = np.flatnonzero(np.diff(moving.astype(int)) == 1)
    ends = np.flatnonzero(np.diff(moving.astype(int)) == -1)
    runs = (ends[: len(starts)] - starts[: len(ends)]) * 10 / 60
    assert runs.min() >= 1.0 and runs.max() <= 8.0


def test_seeded():
    a, b, c = day(seed=1), day(seed=1), day(seed=2)
    np.testing.assert_array_equal(a.occupancy_pct, b.occupancy_pct)
    np.testing.assert_array_equal(a.doors_open, b.doors_open)
    assert not np.array_equal(a.occupancy_pct, c.occupancy_pct)


def test_bad_input():
    t = pd.date_range("2022-03-28", periods=10, freq="10s")
    with pytest.raises(ValueError, match="timezone-aware"):
        stationary(t, latitude_deg=47, longitude_deg=8, heading_deg=0)
    with pytest.raises(ValueError, match="before last_arrival"):
        day(first_departure=pd.Timestamp("2022-03-28 22:00", tz="UTC"))


def test_heading_comes_from_positions_and_holds_at_stops():
    op = day()
    moving = op.speed_kmh > 0
    k = np.flatnonzero(moving[:-1] & moving[1:])
    expected = bearing_deg(
        op.latitude_deg[k], op.longitude_deg[k], op.latitude_deg[k + 1], op.longitude_deg[k + 1]
    )
    np.testing.assert_allclose(op.heading_deg[k], expected, atol=1e-6)
    last_moving = np.maximum.accumulate(np.where(moving, np.arange(len(moving)), 0))
    # (the sample just before a departure already points the new way)
    doors = np.flatnonzero(op.doors_open[:-1] & ~moving[1:])
    np.testing.assert_allclose(op.heading_deg[doors], op.heading_deg[last_moving[doors]])
    # trips in both directions: headings roughly opposite appear
    h = op.heading_deg[moving]
    assert np.ptp(h) > 150
