"""Setpoint rollups (``store.setpoint_rollups``): kept as setpoints are stored, they count each
coach's ticks per 30-minute window exactly as the GROUP BY over the setpoints does — every source
and reason, ticks on and just before window edges, ticks stored late, several coaches — and
equal a rebuild from the setpoints; ``setpoint_counts`` reads them for 30-minute windows on
window boundaries and gives what the raw count gives."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest
from sqlalchemy import delete, select

from helpers.service import T0, at, registered
from trainclimate.service.store import pair_labels, setpoint_rollups
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import Setpoint, SetpointRollup
from trainclimate.service.store.setpoint_rollups import COUNTS

COACHES = ["T-A", "T-B", "U-A", "U-B"]
#: Every (source, reason) the scheduler stores, in turn.
MIX = [
    ("ddpc", "ok"),
    ("rule", "inactive"),
    ("rule", "costing_energy"),
    ("rule", "not_regular"),
    ("rule", "no_model"),
    ("rule", "warmup"),
    ("override", "override"),
    ("fallback", "stale"),
    ("fallback", "error"),
    ("fallback", "solver"),
]
#: The first window (T0 is on a window boundary).
W0 = round(T0.timestamp()) // 1800


@pytest.fixture
def four_coaches_database(db_url):
    database = registered(db_url, [(c, False) for c in COACHES])
    yield database
    database.dispose()


def _row(coach: str, tick, source: str, reason: str) -> dict:
    return {"coach_id": coach, "tick": tick, "t_rule_c": 21.0, "t_ref_c": 21.0} | {
        "source": source,
        "reason": reason,
    }


def _store(db: Database, rows: list[dict]) -> None:
    """Store ``rows`` and count them, in one transaction, as the scheduler does."""
    with db.transaction() as s:
        s.execute(Setpoint.__table__.insert(), rows)
        setpoint_rollups.add(s, rows)


def _fill(db: Database) -> None:
    """Four coaches' 5-minute ticks over three hours, each coach cycling through :data:`MIX`
    from its own offset, stored hour by hour out of order (the first hour last, and one tick
    of it later still); ticks 1 ms and 1 s before a window edge."""
    rows = [
        _row(c, at(m), *MIX[(m // 5 + 3 * i) % len(MIX)])
        for i, c in enumerate(COACHES)
        for m in range(0, 180, 5)
    ]
    rows += [
        _row("T-A", at(30) - timedelta(milliseconds=1), "rule", "inactive"),
        _row("T-B", at(60) - timedelta(seconds=1), "ddpc", "ok"),
    ]
    late = _row("U-B", at(25), "override", "override")
    rows.remove(next(r for r in rows if r["coach_id"] == "U-B" and r["tick"] == at(25)))
    for lo, hi in ((60, 120), (120, 180), (0, 60)):
        _store(db, [r for r in rows if at(lo) <= r["tick"] < at(hi)])
    _store(db, [late])


def _table(db: Database) -> dict[tuple[str, int], tuple[int, ...]]:
    with db.transaction() as s:
        return {
            (r.coach_id, r.window): tuple(getattr(r, c) for c in COUNTS)
            for r in s.scalars(select(SetpointRollup))
        }


def test_increments_count_each_source_and_reason_in_its_window():
    rows = [_row("B", at(0), "ddpc", "ok")]
    rows += [_row("A", at(m), s, r) for m, (s, r) in zip(range(0, 50, 5), MIX, strict=True)]
    rows += [_row("A", at(30) - timedelta(milliseconds=1), "rule", "inactive")]
    got = setpoint_rollups.increments(rows)
    assert [(g["coach_id"], g["window"]) for g in got] == [("A", W0), ("A", W0 + 1), ("B", W0)]
    counts = [tuple(g[c] for c in COUNTS) for g in got]
    # A's first window: ticks 0–25 min (ok, inactive, costing_energy, not_regular, no_model,
    # warmup) and the one 1 ms before 30 min (inactive); its second: 30–45 min (override, stale,
    # error, solver)
    # ticks, ddpc, inactive, no_model, override, fallback, not_regular
    assert counts == [(7, 1, 3, 1, 0, 0, 1), (4, 0, 0, 0, 1, 3, 0), (1, 1, 0, 0, 0, 0, 0)]


def test_the_rollups_count_as_the_group_by(four_coaches_database):
    _fill(four_coaches_database)
    with four_coaches_database.transaction() as s:
        raw = pair_labels.setpoint_counts_raw(s, COACHES, T0, at(180), 30.0)
        kept = pair_labels.setpoint_counts(s, COACHES, T0, at(180), 30.0)
        inner = pair_labels.setpoint_counts(s, ["T-A", "U-B"], at(30), at(120), 30.0)
        inner_raw = pair_labels.setpoint_counts_raw(s, ["T-A", "U-B"], at(30), at(120), 30.0)
    for got, want in ((kept, raw), (inner, inner_raw)):
        assert {c: sorted(w) for c, w in got.items()} == {c: sorted(w) for c, w in want.items()}
        for c in want:
            for w, counts in want[c].items():
                np.testing.assert_array_equal(got[c][w], counts, err_msg=f"{c} {w}")
    assert set(kept) == set(COACHES)
    assert all(sorted(w) == [*range(W0, W0 + 6)] for w in kept.values())
    assert sorted(inner["T-A"]) == [W0 + 1, W0 + 2, W0 + 3]
    # T-A's first window: its six ticks (MIX from 0) and the one 1 ms before 30 min; U-B's (MIX
    # from 9) with its override at 25 min stored last; T-B's second (MIX from 9) with the tick
    # 1 s before 60 min
    # ticks, ddpc, inactive, no_model, override, fallback, not_regular
    assert kept["T-A"][W0].tolist() == [7, 1, 3, 1, 0, 0, 1]
    assert kept["U-B"][W0].tolist() == [6, 1, 2, 0, 1, 1, 1]
    assert kept["T-B"][W0 + 1].tolist() == [7, 2, 2, 1, 0, 1, 1]
    # the 30-minute count reads the rollups: without them it has nothing, the raw count the same
    with four_coaches_database.transaction() as s:
        s.execute(delete(SetpointRollup))
    with four_coaches_database.transaction() as s:
        assert pair_labels.setpoint_counts(s, COACHES, T0, at(180), 30.0) == {}
        assert pair_labels.setpoint_counts_raw(s, COACHES, T0, at(180), 30.0).keys() == raw.keys()


def test_the_rollups_kept_equal_a_rebuild(four_coaches_database):
    _fill(four_coaches_database)
    kept = _table(four_coaches_database)
    with four_coaches_database.transaction() as s:
        assert setpoint_rollups.rebuild(s) == len(kept) == len(COACHES) * 6
    assert _table(four_coaches_database) == kept
    assert sum(v[0] for v in kept.values()) == len(COACHES) * 36 + 2


def test_read_gives_each_coachs_windows_in_order(four_coaches_database):
    _fill(four_coaches_database)
    with four_coaches_database.transaction() as s:
        got = setpoint_rollups.read(s, ["U-A", "T-B", "nobody"], W0 + 2, W0 + 5)
        assert setpoint_rollups.read(s, [], W0, W0 + 6) == {}
        assert setpoint_rollups.read(s, COACHES, W0 + 6, W0 + 8) == {}
    kept = _table(four_coaches_database)
    assert sorted(got) == ["T-B", "U-A"]
    for c, (index, counts) in got.items():
        assert index.dtype == np.int64 and counts.dtype == float
        assert index.tolist() == [W0 + 2, W0 + 3, W0 + 4]
        assert counts.tolist() == [list(kept[(c, w)]) for w in index.tolist()]
