"""Window rollups (``store.rollups``): kept as telemetry arrives, they give the pair comparison's
sums exactly as the raw minutes do — on data with gaps, late rows, overrides, lost links, modes
other than regular, rows off the minute grid and power not reported — and equal a rebuild from
the raw minutes; each coach's comfort state equals the raw look-back's."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest
from sqlalchemy import func, select

from helpers.service import T0, at, flat_row, registered, sim_rows
from trainclimate.service.store import fleet_summary, pair_windows, rollups
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import CoachFeed, Override, Telemetry, WindowRollup
from trainclimate.service.store.pair_labels import SUMS
from trainclimate.service.store.telemetry import insert_rows


def _rows(coach: int, first: int, last: int, changes: dict | None = None) -> list[dict]:
    """Simulated rows of ``coach`` (a parked heating coach: comfort violations too), minutes
    ``first`` … ``last``; ``changes`` maps a minute to the values it replaces."""
    rows = sim_rows(coach, first, last)
    for r in rows:
        minute = round((r["time"] - T0).total_seconds() / 60)
        r.update((changes or {}).get(minute, {}))
    return rows


@pytest.fixture
def two_pairs_database(db_url):
    database = registered(db_url, [("T-A", True), ("T-B", False), ("U-A", True), ("U-B", False)])
    yield database
    database.dispose()


def _store(db: Database, coach: str, rows: list[dict]) -> int:
    with db.transaction() as s:
        return insert_rows(s, coach, rows)


def _fill(db: Database) -> None:
    """Two pairs over two hours, arriving as a feed does: in batches, some late, some twice."""
    lost = {"connected": False}
    # T: A has a gap at 35–37 min and a hot upper deck at 61–65, B a lost link at 50–52, both
    # slumber at 70–79, A's floor heating not reported after minute 90, a row off the grid,
    # power missing on B at 101
    hot = {m: {"t_room_up_c": 27.0} for m in range(61, 66)}  # off the band: discomfort
    a = _rows(0, 1, 120, {**hot, **{m: {"floor_power_kw": None} for m in range(91, 121)}})
    a = [r for r in a if not 35 <= round((r["time"] - T0).total_seconds() / 60) <= 37]
    b = _rows(1, 1, 120, {**{m: lost for m in range(50, 53)}, 101: {"power_kw": None}})
    for r in (*a, *b):
        minute = round((r["time"] - T0).total_seconds() / 60)
        if 70 <= minute <= 79:
            r["mode"] = "slumber"
    # batches of 20 minutes, the last hour of A before its first (late rows), one sent twice
    for lo in (60, 80, 100, 0, 20, 40, 40):
        _store(db, "T-A", [r for r in a if at(lo) < r["time"] <= at(lo + 20)])
    for lo in range(0, 120, 20):
        _store(db, "T-B", [r for r in b if at(lo) < r["time"] <= at(lo + 20)])
    _store(db, "T-B", [flat_row(at(45.5))])  # off the minute grid: counted nowhere
    # U: identical coaches but for an override of U-A over minutes 10–40, and U-B silent
    # after 100 (windows one coach has alone)
    _store(db, "U-A", _rows(2, 1, 120))
    _store(db, "U-B", _rows(2, 1, 100))
    with db.transaction() as s:
        s.add(
            Override(
                coach_id="U-A",
                t_ref_c=21.0,
                starts_at=at(10),
                ends_at=at(40),
                reason="test",
                created_by="test",
            )
        )


def _both_ways(db: Database) -> tuple[dict, dict, dict, list]:
    pairs = [("T-A", "T-B", T0, at(120)), ("U-A", "U-B", T0, at(120))]
    with db.transaction() as s:
        overrides = pair_windows.overrides_over(s, pairs)
        raw = pair_windows.window_sums(s, pairs, 30.0, overrides=overrides)
        kept = pair_windows.pair_grids(s, pairs, 30.0, overrides)
        exact, dirty = rollups.pair_grids(s, pairs, overrides)
    return raw, kept, exact, dirty


def test_the_rollups_give_the_raw_minutes_sums(two_pairs_database):
    _fill(two_pairs_database)
    raw, kept, exact, dirty = _both_ways(two_pairs_database)
    w0 = round(T0.timestamp()) // 1800
    assert set(raw) == set(kept) == {"T-A", "U-A"}
    for pair in raw:
        assert kept[pair].shape == (4, len(SUMS))
        # every window the raw minutes give, and zeros where they give none (no paired minute)
        expected = np.zeros((4, len(SUMS)))
        for w, sums in raw[pair].items():
            expected[w - w0] = sums
        np.testing.assert_allclose(kept[pair], expected, rtol=1e-9, atol=1e-12, err_msg=pair)
    # the rollups give the windows where both coaches have the same minutes counting for the
    # same things; the raw minutes the others: T's gap (35–37) and B's lost link (50–52) in the
    # second window, B's power missing at 101 in the fourth, U's override (10–40: the first
    # two windows) and U-B silent after 100 (the fourth); the slumber, the floor split and the
    # row off the grid stay exact
    assert {(p[0], round(p[2].timestamp()) // 1800 - w0) for p in dirty} == {
        ("T-A", 1),
        ("T-A", 3),
        ("U-A", 0),
        ("U-A", 1),
        ("U-A", 3),
    }
    minutes = SUMS.index("minutes")
    assert list(np.flatnonzero(exact["T-A"][:, minutes])) == [0, 2]
    assert list(np.flatnonzero(exact["U-A"][:, minutes])) == [2]
    # in numbers: T's third window (60–90 min) with ten slumber minutes, the fourth with B's
    # power missing at 101 (affected) and A's floor heating not split off after 90; U's fourth
    # has 10 paired minutes
    third = dict(zip(SUMS, exact["T-A"][2], strict=True))
    assert (third["minutes"], third["counted_minutes"], third["affected_minutes"]) == (30, 20, 0)
    fourth = dict(zip(SUMS, kept["T-A"][3], strict=True))
    assert (fourth["affected_minutes"], fourth["unsplit_minutes"]) == (1, 30)
    assert dict(zip(SUMS, kept["U-A"][3], strict=True))["minutes"] == 10
    assert third["discomfort_0_up_kh"] > 0.05 and third["discomfort_1_up_kh"] < 0.01


def test_the_rollups_kept_at_ingest_equal_a_rebuild_from_the_raw_minutes(two_pairs_database):
    _fill(two_pairs_database)

    def read():
        with two_pairs_database.transaction() as s:
            windows = {
                (r.coach_id, r.window): tuple(
                    getattr(r, c) for c in (*rollups.MASKS, *rollups.TOTALS)
                )
                for r in s.scalars(select(WindowRollup))
            }
            comfort = {
                r.coach_id: (r.first, r.newest, r.last_ok) for r in s.scalars(select(CoachFeed))
            }
            # the oldest and the newest row of each coach, as the telemetry has them
            span = s.execute(
                select(
                    Telemetry.coach_id, func.min(Telemetry.time), func.max(Telemetry.time)
                ).group_by(Telemetry.coach_id)
            ).all()
            assert {cid: c[:2] for cid, c in comfort.items()} == {
                cid: (lo, hi) for cid, lo, hi in span
            }
        return windows, comfort

    kept_windows, kept_comfort = read()
    with two_pairs_database.transaction() as s:
        assert rollups.rebuild(s) == len(kept_windows) == 4 * 4
    rebuilt_windows, rebuilt_comfort = read()
    assert rebuilt_comfort == kept_comfort
    assert set(rebuilt_windows) == set(kept_windows)
    for key, values in kept_windows.items():
        assert values[:5] == rebuilt_windows[key][:5], key  # the masks exactly
        np.testing.assert_allclose(values[5:], rebuilt_windows[key][5:], rtol=1e-9, atol=1e-12)
    # T-A's gap: minutes 35–37 are bits 4–6 of its second window
    present = kept_windows[("T-A", round(T0.timestamp()) // 1800 + 1)][0]
    assert present == rollups.FULL & ~(0b111 << 4)


def test_the_comfort_state_answers_the_attention_lookback(two_pairs_database):
    """A coach's minutes outside comfort up to its newest row, from its comfort state, as the
    raw look-back over its last two hours counts them."""
    hot = {"t_room_up_c": 25.0}
    _store(two_pairs_database, "T-A", [flat_row(at(m)) for m in range(1, 41)])
    _store(two_pairs_database, "T-A", [flat_row(at(m), **hot) for m in range(41, 61)])
    _store(two_pairs_database, "T-B", [flat_row(at(m), **hot) for m in range(1, 31)])
    _store(
        two_pairs_database, "U-A", [flat_row(at(m), **hot, mode="slumber") for m in range(1, 31)]
    )
    with two_pairs_database.transaction() as s:
        ends = {"T-A": at(60), "T-B": at(200), "U-A": at(30), "U-B": at(30)}
        found = fleet_summary.comfort_violations(s, ends)
    # T-A: within comfort until 40, outside since: 20 min; T-B outside from its first row, its
    # look-back (2 h before 200 min) starting at 80 after its newest row: left out; U-A not in
    # regular mode: within comfort; U-B without rows: left out
    assert found == {"T-A": pytest.approx(20.0)}
    with two_pairs_database.transaction() as s:
        ends = {"T-B": at(60)}
        assert fleet_summary.comfort_violations(s, ends) == {"T-B": pytest.approx(90.0)}
    # a late row within comfort moves the last row within comfort forward
    _store(two_pairs_database, "T-B", [flat_row(at(20) - timedelta(seconds=30))])
    with two_pairs_database.transaction() as s:
        assert fleet_summary.comfort_violations(s, {"T-B": at(60)}) == {"T-B": pytest.approx(10.5)}
