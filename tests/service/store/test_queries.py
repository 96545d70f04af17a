"""The range a pair comparison or fleet summary counts (:func:`queries.counted_range`)."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace
from zoneinfo import ZoneInfo

import pandas as pd

from trainclimate.service.store import queries


def test_the_counted_range_starts_at_a_window_boundary_in_the_callers_zone():
    start = datetime(2026, 3, 1, 10, 7, tzinfo=UTC)
    end = start + timedelta(hours=24)
    first, n = queries.counted_range(start, end, None, 30.0)
    assert first == pd.Timestamp("2026-03-01T10:30Z") and n == 47
    # the pair's data begins later: from its first row's minute on
    late = start + timedelta(hours=5, minutes=1)
    assert queries.counted_range(start, end, late, 30.0) == (pd.Timestamp("2026-03-01T15:30Z"), 37)
    # the same instants asked in another zone: the same windows, in that zone (the ranges are
    # kept per zone, not only per instant)
    zurich = ZoneInfo("Europe/Zurich")
    first_local, n_local = queries.counted_range(
        start.astimezone(zurich), end.astimezone(zurich), None, 30.0
    )
    assert (first_local, n_local) == (first, n)
    assert str(first_local.tz) == "Europe/Zurich" and first.tz == UTC
    assert queries.counted_range(start, start + timedelta(minutes=20), None, 30.0)[1] == 0


def test_a_trains_pair_is_its_first_activated_and_first_deactivated_coach_by_id():
    """By id: the first activated and the first deactivated coach, else the first two; the
    pair ordered by id — for a train of two coaches of each kind as for any other."""
    ids = ["T-A", "T-B", "T-C"]
    for n in (0, 1, 2, 3):
        for chosen in itertools.combinations(ids, n):
            for flags in itertools.product((False, True), repeat=n):
                pairs = zip(chosen, flags, strict=True)
                coaches = [SimpleNamespace(id=i, ddpc_active=f) for i, f in pairs]
                on = [c for c in coaches if c.ddpc_active]
                off = [c for c in coaches if not c.ddpc_active]
                want = [on[0], off[0]] if on and off else coaches[:2] if n >= 2 else None
                got = queries.pick_pair(coaches)
                if want is None:
                    assert got is None
                else:
                    assert [c.id for c in got] == sorted(c.id for c in want)
