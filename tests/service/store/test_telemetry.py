"""The controller's samples from stored 1-minute telemetry (``telemetry.controller_samples``):
the ticks, the intervals between them, and where the lead-in is cut."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.service import PG_SKIP, PG_URL, drop_pg_database, pg_database
from trainclimate.service.store.telemetry import VALUE_COLS, CoachRows, controller_samples

PERIOD_S = 300.0
T0 = 1_732_766_400.0  # 2024-11-28T04:00Z, a multiple of 5 min


def rows(minutes: int, *, missing=(), nan_at=(), not_regular=()) -> CoachRows:
    """Rows ending at T0 + 1 … T0 + ``minutes`` min; each value is a known function of the minute
    m (deck temperatures 20 + m/100 and ±0.5, T_ref 21 + m/1000, disturbances 100·j + m), with
    minutes ``missing`` left out, a NaN deck temperature at ``nan_at`` and mode slumber at
    ``not_regular``."""
    m = np.array([k for k in range(1, minutes + 1) if k not in missing], float)
    v = np.empty((len(m), len(VALUE_COLS)))
    col = {c: i for i, c in enumerate(VALUE_COLS)}
    v[:, col["t_room_up_c"]] = 20.5 + m / 100
    v[:, col["t_room_mid_c"]] = 20.0 + m / 100
    v[:, col["t_room_low_c"]] = 19.5 + m / 100
    v[:, col["t_ref_c"]] = 21.0 + m / 1000
    v[:, col["t_rule_c"]] = 22.0
    for j, c in enumerate(("t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh")):
        v[:, col[c]] = 100.0 * j + m
    v[:, col["ghi_w_m2"]] = 0.0
    v[:, col["power_kw"]] = 5.0
    v[np.isin(m, nan_at), col["t_room_mid_c"]] = np.nan
    return CoachRows(T0 + 60.0 * m, v, ~np.isin(m, not_regular))


def test_samples_at_every_tick_with_the_interval_means_between_them():
    s = controller_samples(rows(30), T0 + 30 * 60, PERIOD_S)
    # ticks at 5, 10, …, 30 min: the reading at a tick is the row ending there
    assert s.times_s.tolist() == [T0 + 60.0 * k for k in (5, 10, 15, 20, 25, 30)]
    np.testing.assert_allclose(s.y[:, 1], [20.0 + k / 100 for k in (5, 10, 15, 20, 25, 30)])
    np.testing.assert_allclose(s.y[0], [20.55, 20.05, 19.55])
    # u and d over the five intervals between them: the means of the rows in (t_k, t_k + Δ]
    np.testing.assert_allclose(s.u, [21.0 + (k + 3) / 1000 for k in (5, 10, 15, 20, 25)])
    np.testing.assert_allclose(s.d_past[:, 0], [k + 3.0 for k in (5, 10, 15, 20, 25)])
    np.testing.assert_allclose(s.d_past[-1], [28.0, 128.0, 228.0, 328.0, 428.0])
    np.testing.assert_allclose(s.d_now, s.d_past[-1])
    assert s.u_prev == pytest.approx(21.030) and s.t_rule_now == 22.0
    assert s.regular and s.last_time_s == T0 + 1800.0


def test_the_lead_in_is_cut_at_a_gap_a_nan_or_a_minute_out_of_regular_mode():
    tick = T0 + 30 * 60
    # a missing minute in (15, 20] min: the interval ending at 20 is incomplete, so the samples
    # start at the tick of 20 min
    s = controller_samples(rows(30, missing=(17,)), tick, PERIOD_S)
    assert s.times_s.tolist() == [T0 + 60.0 * k for k in (20, 25, 30)]
    assert len(s.u) == 2 and len(s.d_past) == 2
    # a NaN deck temperature at the tick of 15 min: no reading there, the samples start at 20
    s = controller_samples(rows(30, nan_at=(15,)), tick, PERIOD_S)
    assert s.times_s.tolist() == [T0 + 60.0 * k for k in (20, 25, 30)]
    # … but a NaN deck temperature between ticks does not cut: only the readings at ticks count
    s = controller_samples(rows(30, nan_at=(12,)), tick, PERIOD_S)
    assert len(s.times_s) == 6
    # slumber in (25, 30]: the newest interval is not regular, only the tick itself is left
    s = controller_samples(rows(30, not_regular=(27,)), tick, PERIOD_S)
    assert s.times_s.tolist() == [tick] and len(s.u) == 0 and s.d_now is None
    assert s.regular  # the newest minute is regular again


def _samples_walking_back(rows: CoachRows, tick_s: float, period_s: float) -> tuple:
    """The samples as a loop walking back tick by tick (how they were first written): times,
    y, u, d_past, d_now."""
    _y = [VALUE_COLS.index(c) for c in ("t_room_up_c", "t_room_mid_c", "t_room_low_c")]
    _u = VALUE_COLS.index("t_ref_c")
    _d = [
        VALUE_COLS.index(c)
        for c in ("t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh")
    ]
    minutes = round(period_s / 60.0)
    time_s, v = rows.time_s, rows.values
    times, ys, us, ds = [], [], [], []
    if len(time_s) and time_s[-1] >= tick_s - 60.0:
        y_ok = ~np.isnan(v[:, _y]).any(axis=1)
        block_ok = rows.regular & ~np.isnan(v[:, [_u, *_d]]).any(axis=1)
        t = tick_s
        while True:
            hi = np.searchsorted(time_s, t, side="right")
            lo = np.searchsorted(time_s, t - 60.0, side="right")
            if hi == lo or not y_ok[lo:hi].all():
                break
            times.append(t)
            ys.append(v[lo:hi, _y].mean(axis=0))
            lo = np.searchsorted(time_s, t - period_s, side="right")
            if hi - lo < minutes or not block_ok[lo:hi].all():
                break
            us.append(float(v[lo:hi, _u].mean()))
            ds.append(v[lo:hi, _d].mean(axis=0))
            t -= period_s
    n = len(times)
    us, ds = us[: n - 1][::-1], ds[: n - 1][::-1]
    return (
        np.array(times[::-1], float),
        np.array(ys[::-1], float).reshape(-1, 3),
        np.array(us, float),
        np.array(ds, float).reshape(-1, 5),
        ds[-1] if ds else None,
    )


@pytest.mark.parametrize("period_s", [300.0, 600.0])
def test_the_samples_are_those_of_walking_back_tick_by_tick(period_s):
    """On 300 random coaches' rows — minutes missing, off the grid or twice, NaN values, other
    modes, rows ending before or after the tick — the samples equal the loop's, bit for bit."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        n = int(rng.integers(0, 90))
        minute = np.sort(rng.choice(np.arange(1, 100), size=n, replace=False)).astype(float)
        minute[rng.random(n) < 0.05] += 0.5  # off the minute grid
        time_s = T0 + 60.0 * minute
        v = rng.normal(20.0, 2.0, (n, len(VALUE_COLS)))
        v[rng.random((n, len(VALUE_COLS))) < 0.01] = np.nan
        regular = rng.random(n) > 0.03
        tick = T0 + 60.0 * float(rng.integers(60, 100))
        r = CoachRows(time_s, v, regular)
        got = controller_samples(r, tick, period_s)
        times, y, u, d_past, d_now = _samples_walking_back(r, tick, period_s)
        np.testing.assert_array_equal(got.times_s, times)
        np.testing.assert_array_equal(got.y, y)
        np.testing.assert_array_equal(got.u, u)
        np.testing.assert_array_equal(got.d_past, d_past)
        if d_now is None:
            assert got.d_now is None
        else:
            np.testing.assert_array_equal(got.d_now, d_now)


def test_stale_or_no_telemetry_gives_no_samples():
    # the newest row is more than a minute before the tick
    s = controller_samples(rows(28), T0 + 30 * 60, PERIOD_S)
    assert len(s.times_s) == 0 and s.y.shape == (0, 3) and s.d_past.shape == (0, 5)
    assert s.last_time_s == T0 + 28 * 60 and s.u_prev == pytest.approx(21.028)
    empty = CoachRows(np.empty(0), np.empty((0, len(VALUE_COLS))), np.empty(0, bool))
    s = controller_samples(empty, T0, PERIOD_S)
    assert s.last_time_s is None and np.isnan(s.u_prev) and np.isnan(s.t_rule_now)
    assert not s.regular and len(s.times_s) == 0


def test_load_rows_reads_arrays_from_either_database(db_url):
    """``load_rows``: each coach's rows in the range as arrays — exact times (also off the
    minute grid), NaN for a value not reported, regular mode — and empty arrays for a coach
    without rows."""
    from helpers.service import at, flat_row
    from trainclimate.service.store.db import Database, migrate
    from trainclimate.service.store.models import Coach, Train
    from trainclimate.service.store.telemetry import insert_rows, load_rows

    migrate(db_url)
    db = Database(db_url)
    try:
        with db.transaction() as s:
            s.add(Train(id="T", name="T"))
            s.flush()
            s.add_all([Coach(id=c, train_id="T") for c in ("T-A", "T-B", "T-C")])
            s.flush()
            rows = [flat_row(at(m)) for m in (1, 2, 3)]
            rows[1].update(power_kw=None, mode="slumber")
            insert_rows(s, "T-B", [flat_row(at(2), t_room_up_c=23.25)])
            insert_rows(s, "T-A", [flat_row(at(3.5))])  # stored before the rows it follows
            insert_rows(s, "T-A", rows)
        with db.transaction() as s:
            got = load_rows(s, ["T-A", "T-B", "T-C"], at(1), at(3.5))
    finally:
        db.dispose()
    a, b, c = got["T-A"], got["T-B"], got["T-C"]
    assert a.time_s.tolist() == [at(m).timestamp() for m in (2, 3, 3.5)]
    assert np.isnan(a.column("power_kw")[0]) and a.column("power_kw")[1] == 10.0
    assert a.regular.tolist() == [False, True, True]
    assert b.column("t_room_up_c").tolist() == [23.25] and b.values.shape == (1, len(VALUE_COLS))
    assert c.time_s.shape == (0,) and c.values.shape == (0, len(VALUE_COLS))


@pytest.mark.skipif(not PG_URL, reason=PG_SKIP)
def test_packed_rows_are_the_query_s_rows_and_refuse_a_null_or_a_misshapen_array():
    """PostgreSQL packs the rows into one value: read back they are the query's, as integers
    and floats to the bit; none is an empty array; a NULL, which would drop its row from the
    packing, is an error rather than a row lost."""
    from psycopg import sql

    from trainclimate.service.store.binary_rows import RowShapeError, packed_rows
    from trainclimate.service.store.db import Database

    dtype = np.dtype([("k", np.int64), ("x", np.float64)])
    url, name = pg_database()
    db = Database(url)
    try:
        with db.transaction() as s:
            got = packed_rows(
                s,
                sql.SQL(
                    "SELECT i, i / 7.0::float8 "
                    "FROM generate_series(-3::int8, 1099511627776, 274877906944) i"
                ),
                dtype,
            )
            order = np.argsort(got["k"])
            assert got["k"][order].tolist() == [-3 + i * 2**38 for i in range(5)]
            assert got["x"][order].tolist() == [(-3 + i * 2**38) / 7.0 for i in range(5)]
            assert got.dtype == dtype
            assert packed_rows(
                s, sql.SQL("SELECT 1::int8, 1.0::float8 WHERE false"), dtype
            ).shape == (0,)
            with pytest.raises(RowShapeError, match="NULL"):
                packed_rows(
                    s, sql.SQL("SELECT 1::int8, NULL::float8 UNION ALL SELECT 2, 2.0"), dtype
                )
            # a bytea of float64 values (as numpy writes them) read as a fixed-size field; one
            # of another size is an error, not a row shifted into the next
            arrays = np.dtype([("k", np.int64), ("v", np.float64, (3,))])
            values = np.array([[0.5, -1e300, 3.0], [np.pi, 0.0, -0.0]])
            first = sql.SQL("SELECT 7::int8, {}::bytea").format(values[0].tobytes())
            got = packed_rows(
                s,
                sql.SQL("{} UNION ALL SELECT 8, {}::bytea").format(first, values[1].tobytes()),
                arrays,
            )
            order = np.argsort(got["k"])
            assert got["k"][order].tolist() == [7, 8]
            assert got["v"][order].tobytes() == values.tobytes()
            for other in (np.zeros(1).tobytes()[:1], np.zeros(4).tobytes()):
                with pytest.raises(RowShapeError, match="misshapen"):
                    packed_rows(
                        s,
                        sql.SQL("{} UNION ALL SELECT 9, {}::bytea").format(first, other),
                        arrays,
                    )
    finally:
        db.dispose()
        drop_pg_database(name)


@pytest.mark.skipif(not PG_URL, reason=PG_SKIP)
def test_arrays_sent_as_one_literal_arrive_as_the_values_and_refuse_a_space():
    """The arrays a summary sends (coach ids, days, windows) arrive as the values, in order and
    of their type, an empty one empty; a value holding a space or empty, which would split or
    vanish, is refused."""
    from psycopg import sql

    from trainclimate.service.store.binary_rows import array_of, rows
    from trainclimate.service.store.db import Database

    url, name = pg_database()
    db = Database(url)
    try:
        with db.transaction() as s:
            ids = ["124-A", "C000.b_1", "7"]
            query = sql.SQL("SELECT {}, {}, {}, {}").format(
                array_of(ids, "text"),
                array_of([-3, 2**40], "int8"),
                array_of([0, 23], "int4"),
                array_of([], "text"),
            )
            assert rows(s, query) == [(ids, [-3, 2**40], [0, 23], [])]
        for bad in (["124 A"], ["124-A", ""]):
            with pytest.raises(ValueError, match="empty or holds a space"):
                array_of(bad, "text")
    finally:
        db.dispose()
        drop_pg_database(name)
