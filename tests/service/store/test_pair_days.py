"""Pair days and fleet days on SQLite and PostgreSQL: the fleet summary read from them equals the
summary read from the rollups alone, over ranges that start and end anywhere in a day and on its
switch hour, on data with role changes at any window (one just before the switch hour, whose
lead-in runs into the next day), hours without setpoints, fallbacks, reference windows, gaps, a
lost link, a coach out of regular mode and an override; a fleet day is used only where it pools
exactly the pair days read; a late row drops the pair days it changes and their fleet days, and
the next build makes them again, as it does the days retention cuts into; the scheduler makes
them a few at a time; the day still running is kept in the read cache and only its new windows
are read."""

from __future__ import annotations

import shutil
from collections import Counter
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from helpers.service import PG_SKIP, PG_URL, drop_pg_database, flat_row, pg_database
from trainclimate.analysis import trial_plan
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.settings import Settings
from trainclimate.service.store import (
    comparison,
    fleet_days,
    fleet_summary,
    pair_days,
    pair_days_read,
    pair_windows,
    partitions,
    setpoint_rollups,
)
from trainclimate.service.store.cache import ReadCache
from trainclimate.service.store.commands import ingest
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import (
    Coach,
    FleetDay,
    Override,
    PairDay,
    Setpoint,
    Train,
)
from trainclimate.service.store.telemetry import insert_rows

#: Midnight UTC; the service days switch at 02:00 UTC (03:00 in Zurich in winter).
START = datetime(2024, 11, 4, tzinfo=UTC)
DAYS = 5
MINUTES = DAYS * 1440 + 300
#: What each window's setpoints say: the layer on A (B on T_rule, layer off), on B, on neither
#: (reference), a fallback on A, the HVAC out of regular mode, the layer on both, no setpoint.
ROLES = ("A", "B", "reference", "fallback", "slumber", "both", "none")
#: The minute of day 2 left out of the load, posted late.
LATE_MINUTE = 2 * 1440 + 700


def _plan(rng) -> list[str]:
    """Each 30-minute window's roles, in blocks of 1–8 windows, with a change at 01:30 UTC on
    day 1 (the last window of service day 0)."""
    out: list[str] = []
    while len(out) < MINUTES // 30 + 2:
        out += [str(rng.choice(ROLES, p=[0.33, 0.33, 0.1, 0.06, 0.06, 0.06, 0.06]))] * int(
            rng.integers(1, 9)
        )
    last_window = (1440 + 90) // 30  # 01:30 UTC on day 1
    out[last_window - 4 : last_window] = ["A"] * 4
    out[last_window : last_window + 6] = ["B"] * 6
    return out


def _setpoints(coach: str, side: str, plan: list[str]) -> list[dict]:
    rows = []
    for m in range(0, MINUTES, 5):
        role = plan[m // 30]
        if role == "none":
            continue
        if role in (side, "both"):
            source, reason = "ddpc", "ok"
        elif role == "fallback" and side == "A":
            source, reason = "fallback", "stale_data"
        elif role == "slumber":
            source, reason = "rule", "not_regular"
        else:
            source, reason = "rule", "inactive"
        tick = START + timedelta(minutes=m)
        rows.append(
            {"coach_id": coach, "tick": tick, "t_rule_c": 22.0, "t_ref_c": 22.0}
            | {"source": source, "reason": reason}
        )
    return rows


def _telemetry(rng, side: str, split: bool) -> list[dict]:
    rows = []
    warm = rng.random(MINUTES + 1) < 0.02
    for m in range(1, MINUTES + 1):
        if rng.random() < 0.003 or (side == "A" and m == LATE_MINUTE):
            continue  # a gap (and the late minute)
        power = (8.0 if side == "A" else 10.0) + rng.normal(0.0, 0.5)
        values = {
            "power_kw": power,
            "floor_power_kw": 1.5 if split else None,
            "t_room_mid_c": 23.8 if warm[m] else 21.5,
            "connected": not (side == "B" and 3000 <= m <= 3002),
            "mode": "slumber" if side == "A" and 4400 <= m <= 4460 else "regular",
        }
        rows.append(flat_row(START + timedelta(minutes=m), **values))
    return rows


def _override(coach: str, starts: datetime, minutes: int) -> Override:
    """An override of ``coach`` to 21 °C from ``starts`` for ``minutes``."""
    return Override(
        coach_id=coach,
        t_ref_c=21.0,
        starts_at=starts,
        ends_at=starts + timedelta(minutes=minutes),
        reason="test",
        created_by="test",
    )


def _load(url: str) -> None:
    """Two trains (X with the floor heating's share reported, Y without) over five service
    days, an override on Y-A over day 3; no pair days."""
    migrate(url)
    db = Database(url)
    rng = np.random.default_rng(7)
    with db.transaction() as s:
        for train, split in (("X", True), ("Y", False)):
            s.add(Train(id=train, name=train))
            s.flush()
            plan = _plan(rng)
            for side in ("A", "B"):
                cid = f"{train}-{side}"
                s.add(Coach(id=cid, train_id=train, fleet="live", ddpc_active=side == "A"))
                s.flush()
                insert_rows(s, cid, _telemetry(rng, side, split))
                rows = _setpoints(cid, side, plan)
                s.execute(Setpoint.__table__.insert(), rows)
                setpoint_rollups.add(s, rows)
                s.get(Coach, cid).last_tick = START + timedelta(minutes=MINUTES)
        s.add(_override("Y-A", START + timedelta(days=3, hours=5), 40))
    db.dispose()


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def loaded(request, tmp_path_factory):
    """The fleet of :func:`_load`, loaded once per module into a SQLite file or a PostgreSQL
    database (skipped without a server) that each test copies."""
    if request.param == "sqlite":
        path = tmp_path_factory.mktemp("pair-days") / "loaded.db"
        _load(f"sqlite:///{path}")
        yield path
        return
    if not PG_URL:
        pytest.skip(PG_SKIP)
    url, name = pg_database()
    try:
        _load(url)
        yield name
    finally:
        drop_pg_database(name)


@pytest.fixture
def fleet(loaded, tmp_path):
    """A copy of the loaded fleet of its own (a file copied, a database made from it as a
    template)."""
    if isinstance(loaded, Path):
        url = f"sqlite:///{tmp_path / 'fleet.db'}"
        shutil.copyfile(loaded, tmp_path / "fleet.db")
        name = None
    else:
        url, name = pg_database(template=loaded)
    db = Database(url)
    yield db
    db.dispose()
    if name is not None:
        drop_pg_database(name)


def _summaries(db) -> dict:
    """The fleet summary over ranges that start and end anywhere and on a switch hour."""
    out = {}
    with db.transaction() as s:
        for end_min in (MINUTES, 4 * 1440 + 120, 3 * 1440 + 977, 2 * 1440 + 120 + 30):
            end = START + timedelta(minutes=end_min)
            for hours in (6, 24, 30, 48, 72, 98, 120):
                out[(end_min, hours)] = fleet_summary.summary(s, [], hours, end)
    return out


def _comparisons(db, summaries: dict) -> dict:
    """Each train's pair comparison (:func:`.comparison.comparison`, every window of the range
    at once) over each range of ``summaries``, as the summary's train entries show it."""
    out = {}
    with db.transaction() as s:
        for key, summary in summaries.items():
            trains = []
            for entry in summary["trains"]:
                c = comparison.comparison(
                    s, s.get(Train, entry["id"]), entry["start"], entry["end"]
                )
                trains.append({k: c[k] for k in entry if k not in SHOWN_ONLY})
            out[key] = {"trains": trains}
    return out


def _figures(summaries: dict) -> dict:
    """The summaries' train entries without what the comparison shows otherwise."""
    return {
        key: {"trains": [{k: v for k, v in t.items() if k not in SHOWN_ONLY} for t in s["trains"]]}
        for key, s in summaries.items()
    }


#: A summary's train entry's keys that are not figures.
SHOWN_ONLY = {"id", "name", "plan", "coaches", "activated", "deactivated", "start", "end"}


def _flat(value, path=()) -> dict:
    if isinstance(value, dict):
        return {k: v for key in value for k, v in _flat(value[key], (*path, key)).items()}
    if isinstance(value, list | tuple):
        return {k: v for i, x in enumerate(value) for k, v in _flat(x, (*path, i)).items()}
    return {path: value}


def _assert_same(got: dict, want: dict) -> None:
    for key in want:
        g, w = _flat(got[key]), _flat(want[key])
        assert g.keys() == w.keys(), key
        for path, value in w.items():
            if isinstance(value, float):
                assert g[path] == pytest.approx(value, rel=1e-9, abs=1e-9), (key, path)
            else:
                assert g[path] == value, (key, path)


def _build(db) -> int:
    with db.transaction() as s:
        return pair_days.build(s, pair_days.fleet_pairs(s, START + timedelta(days=DAYS)))


def test_the_summary_from_pair_days_equals_the_rollups(fleet, monkeypatch):
    want = _summaries(fleet)
    # read day by day from the rollups, each train's figures are its comparison's, whose
    # windows are taken all at once (the range's start is not a day's)
    _assert_same(_figures(want), _comparisons(fleet, want))
    trains = want[(MINUTES, 120)]["trains"]
    assert [t["counted_windows"] for t in trains] != [0, 0]
    assert {r for t in trains for r in t["excluded_minutes_by_reason"]} >= {
        "plan_switch",
        "fallback",
        "no_setpoint",
        "mixed_roles",
        "missing_data",
        "disconnected",
        "override",
        "not_regular",
    }
    # service days 0 … 4 are over (the data runs to 05:00 UTC on day 5); day −1 holds the first
    # two hours
    assert _build(fleet) == 2 * 6
    assert _build(fleet) == 0  # nothing more is due
    used = []
    assemble = pair_days_read._assemble

    def spied(days, stored, executor):
        used.extend(d for mine in days for d in mine if not isinstance(d, pair_days.Day))
        return assemble(days, stored, executor)

    monkeypatch.setattr(pair_days_read, "_assemble", spied)
    got = _summaries(fleet)
    _assert_same(got, want)
    _assert_same(_figures(got), _comparisons(fleet, got))
    assert len(used) > 20  # whole days were read from their pair days


def test_a_summary_in_chunks_of_one_train_is_the_one_in_a_single_chunk(fleet, monkeypatch):
    _build(fleet)  # days from their pair days, and partial ones from their windows
    want = _summaries(fleet)
    sizes = []
    chunks = fleet_summary._chunks

    def spied(missing):
        out = chunks(missing)
        sizes.append([len(c) for c in out])
        return out

    monkeypatch.setattr(fleet_summary, "_chunks", spied)
    assert _summaries(fleet) == want
    assert sizes and all(s == [2] for s in sizes)
    sizes.clear()
    monkeypatch.setattr(fleet_summary, "_CHUNK_PAIR_DAYS", 1)
    assert _summaries(fleet) == want
    assert sizes and all(s == [1, 1] for s in sizes)


def test_a_chunk_holds_at_most_its_pair_days():
    def missing(pairs: int, days: float) -> list:
        hi = START + timedelta(days=days)
        return [(("a", "b", START, hi), 2, None, None)] * pairs

    assert fleet_summary._CHUNK_PAIR_DAYS == 8192
    # a range touches its whole days and a partial day at either end
    assert [len(c) for c in fleet_summary._chunks(missing(450, 30))] == [256, 194]
    assert [len(c) for c in fleet_summary._chunks(missing(450, 31))] == [248, 202]
    assert [len(c) for c in fleet_summary._chunks(missing(1000, 7))] == [910, 90]
    assert [len(c) for c in fleet_summary._chunks(missing(450, 0.25))] == [450]
    assert fleet_summary._chunks([]) == []


def test_a_late_row_drops_the_days_it_changes_and_they_are_made_again(fleet):
    assert _build(fleet) == 12
    late = START + timedelta(minutes=LATE_MINUTE)
    with fleet.transaction() as s:
        ingest(s, "X-A", [flat_row(late, power_kw=30.0)])
    with fleet.transaction() as s:
        kept = {(d.coach_0, d.day) for d in s.query(PairDay)}
    late_day = trial_plan.service_day(pair_days.pd.Timestamp(late), 3).toordinal()
    assert ("X-A", late_day) not in kept and ("X-A", late_day - 1) in kept
    assert ("Y-A", late_day) in kept  # the other train's are unchanged
    # read from the rollups where the pair day is gone, and equal to them once made again
    with fleet.transaction() as s:
        pair_days.forget_all(s)
    want = _summaries(fleet)
    assert _build(fleet) == 12
    with fleet.transaction() as s:
        pair_days.forget(s, {"X-A": pair_days.rollups.window_of(late)})
    _assert_same(_summaries(fleet), want)
    assert _build(fleet) >= 1
    _assert_same(_summaries(fleet), want)


def _fleet_days(db) -> dict[int, tuple]:
    """The fleet days stored: day → (pairs pooled, digest)."""
    with db.transaction() as s:
        return {d.day: (d.pairs, d.digest) for d in s.query(FleetDay)}


def test_fleet_days_pool_exactly_the_pair_days_read(fleet, monkeypatch):
    assert _build(fleet) == 12
    want = _summaries(fleet)  # each pair day's chart pooled by the summary itself
    with fleet.transaction() as s:
        assert fleet_days.build(s) == 6  # both trains switch at the same hour: 6 service days
        assert fleet_days.build(s) == 0
    stored = _fleet_days(fleet)
    assert {n for n, _ in stored.values()} == {2}
    read, by_pairs = [], []  # the pair days read whole, those whose charts were pooled here
    charts, pair_charts = fleet_days.charts, fleet_days._pair_charts

    def spied_charts(session, pairs):
        read.extend(
            (c0, c1, hour, day, digest)
            for c0, c1, hour, days, digests in pairs
            for day, digest in zip(days.tolist(), digests.tolist(), strict=True)
        )
        return charts(session, pairs)

    def spied_pair_charts(session, keys):
        by_pairs.append(keys)
        return pair_charts(session, keys)

    monkeypatch.setattr(fleet_days, "charts", spied_charts)
    monkeypatch.setattr(fleet_days, "_pair_charts", spied_pair_charts)
    got = _summaries(fleet)
    _assert_same(got, want)
    # a day's chart comes from its fleet day unless a range read only one train's pair day
    # for it (the other train's entered from another lead-in state: read from its windows)
    assert all(
        len({k[:2] for k in keys if k[3] == d}) == 1 for keys in by_pairs for *_, d, _ in keys
    )
    assert len(read) > 60 and sum(map(len, by_pairs)) < 0.1 * len(read)
    assert sum(w["trains"] == 2 for w in got[(MINUTES, 120)]["windows"]) > 20
    # a fleet day that does not pool the pair days read is not used: their charts are
    day = Counter(k[3] for k in read).most_common(1)[0][0]
    with fleet.transaction() as s:
        s.query(FleetDay).filter(FleetDay.day == day).update({"digest": FleetDay.digest + 1})
    by_pairs.clear()
    _assert_same(_summaries(fleet), want)
    assert day in {k[3] for keys in by_pairs for k in keys}
    # a late row drops its pair day and that day's fleet day; both are made again
    late = START + timedelta(minutes=LATE_MINUTE)
    with fleet.transaction() as s:
        ingest(s, "X-A", [flat_row(late, power_kw=30.0)])
    late_day = trial_plan.service_day(pair_days.pd.Timestamp(late), 3).toordinal()
    kept = _fleet_days(fleet)
    assert late_day not in kept and late_day - 1 in kept
    with fleet.transaction() as s:
        pair_days.forget_all(s)
    want = _summaries(fleet)
    assert _build(fleet) == 12 and _fleet_days(fleet) == {}
    with fleet.transaction() as s:
        assert fleet_days.build(s, max_days=2) == 2
        assert fleet_days.build(s) == 4
    assert _fleet_days(fleet).keys() == stored.keys()
    read.clear()
    by_pairs.clear()
    _assert_same(_summaries(fleet), want)
    assert len(read) > 60 and sum(map(len, by_pairs)) < 0.1 * len(read)


def test_a_fleet_day_keeps_its_pair_days_as_a_summary_reads_them(fleet, monkeypatch):
    """A fleet day keeps its members' rows: each pair day's coaches, lead-in states, chart
    digest and figures. A summary reads whole days from them — kept in the read cache, read
    from the pair days themselves only for the days without a fleet day — and a fleet day made
    again after a late row (a new version) replaces the rows kept: the summaries through the
    cache equal those without it throughout."""
    assert _build(fleet) == 12
    with fleet.transaction() as s:
        assert fleet_days.build(s) == 6
        for f in s.query(FleetDay):
            days = (
                s.query(PairDay)
                .filter(PairDay.day == f.day, PairDay.switch_hour == f.switch_hour)
                .order_by(PairDay.coach_0, PairDay.coach_1)
                .all()
            )
            assert f.members.split("\n") == [f"{d.coach_0} {d.coach_1}" for d in days]
            members = np.frombuffer(f.member_rows, fleet_days.MEMBER)
            for m, d in zip(members, days, strict=True):
                assert [int(m[n]) for n in fleet_days.MEMBER_INTEGERS] == [
                    d.entering_label,
                    d.entering_age,
                    d.exiting_label,
                    d.exiting_age,
                    d.chart_digest,
                ]
                assert m["fields"].tobytes() == d.fields
    own_rows: list[list[int]] = []  # the days read from the pair days' own rows, per read
    stored_rows = pair_days_read._stored_rows

    def spied(session, keys, days):
        rows = stored_rows(session, keys, days)
        own_rows.append(sorted(set(rows["day"].tolist())))
        return rows

    monkeypatch.setattr(pair_days_read, "_stored_rows", spied)
    cache = ReadCache(256)
    end = START + timedelta(minutes=MINUTES)

    def both(hours: float, at: datetime = end) -> dict:
        with fleet.transaction() as s:
            got = fleet_summary.summary(s, [], hours, at, cache)
        with fleet.transaction() as s:
            _assert_same({0: got}, {0: fleet_summary.summary(s, [], hours, at)})
        return got

    both(120)  # service days 0 (from 05:00 UTC) to 5 (running, no pair day yet)
    kept = {k for k in cache._answers if k[0] == "fleet-day"}
    assert len(kept) == 5
    own_rows.clear()
    both(100, end - timedelta(minutes=45))  # a new range: every pair day from a fleet day
    assert own_rows and all(days == [] for days in own_rows)
    # a late row drops a pair day and its fleet day; both made again (another version)
    late = START + timedelta(minutes=LATE_MINUTE)
    with fleet.transaction() as s:
        ingest(s, "X-A", [flat_row(late, power_kw=30.0)])
    late_day = trial_plan.service_day(pair_days.pd.Timestamp(late), 3).toordinal()
    own_rows.clear()
    both(120)  # the day without a fleet day from its pair days
    assert any(late_day in days for days in own_rows)
    assert _build(fleet) >= 1
    with fleet.transaction() as s:
        assert fleet_days.build(s) >= 1
    versions = {k: cache._answers[k][0] for k in kept}
    both(90, end - timedelta(minutes=75))  # a new range (the last one's figures are kept)
    assert {k for k, v in versions.items() if cache._answers[k][0] != v} >= {
        ("fleet-day", 3, late_day)
    }


def test_a_partial_day_reads_the_windows_asked_for_and_no_other(fleet):
    """The windows [a, b) of a pair day (a range's partial first or last day) are its stored
    windows from a to b, to the bit, cut to those it holds: on PostgreSQL the server sends only
    them."""
    _build(fleet)
    with fleet.transaction() as s:
        days = s.query(PairDay).order_by(PairDay.coach_0, PairDay.day).all()
        assert days
        for d in days:
            key = (d.coach_0, d.coach_1, d.switch_hour, d.day)
            grid, label, code0 = pair_days.unpack_windows(d.windows, d.minutes)
            f, n = d.first_window, d.windows
            for a, b in ((f, f + n), (f + 3, f + 11), (f - 5, f + 2), (f + n - 4, f + n + 9)):
                [(first, g, lab, code)] = pair_days.stored_windows(s, {key: (a, b)}).values()
                j0, j1 = max(a - f, 0), min(b - f, n)
                assert first == f + j0
                assert g.tobytes() == grid[j0:j1].tobytes()
                assert lab.tolist() == label[j0:j1].tolist()
                assert code.tolist() == code0[j0:j1].tolist()
        # many at once, of different lengths, one of them empty: each as read alone
        wanted = {
            (d.coach_0, d.coach_1, d.switch_hour, d.day): (
                d.first_window + k % 5,
                d.first_window + (k * 7) % (d.windows + 3) if k % 4 else d.first_window,
            )
            for k, d in enumerate(days)
        }
        together = pair_days.stored_windows(s, wanted)
        assert together.keys() == wanted.keys()
        for key, bounds in wanted.items():
            [alone] = pair_days.stored_windows(s, {key: bounds}).values()
            assert together[key][0] == alone[0]
            for x, y in zip(together[key][1:], alone[1:], strict=True):
                assert x.shape == y.shape and x.tobytes() == y.tobytes()


def test_a_summary_is_read_again_when_a_pair_day_changes_under_it(fleet, monkeypatch):
    """A pair day rebuilt between a summary's reads of its fields and of its chart: the chart
    read finds the digest it read gone, and the trains' figures are read again, uncached."""
    assert _build(fleet) == 12
    with fleet.transaction() as s:
        want = fleet_summary.summary(s, [], 72, START + timedelta(minutes=MINUTES))
        lo, hi = START + timedelta(days=1), START + timedelta(days=4)
        read = pair_days_read.pair_results(s, [("X-A", "X-B", lo, hi)], [3], [])[0]
    days, digests = read["chart_days"]  # the whole days read from their pair days
    assert len(days) == len(digests) >= 2
    with pytest.raises(pair_days.PairDaysChangedError), fleet.transaction() as s:
        fleet_days.charts(s, [("X-A", "X-B", 3, days[:1], np.array([12345]))])
    charts, calls = fleet_days.charts, []

    def changed_once(session, read):
        calls.append(len(read))
        if len(calls) == 1:
            raise pair_days.PairDaysChangedError("rebuilt meanwhile")
        return charts(session, read)

    monkeypatch.setattr(fleet_days, "charts", changed_once)
    cache = ReadCache(16)
    with fleet.transaction() as s:
        got = fleet_summary.summary(s, [], 72, START + timedelta(minutes=MINUTES), cache)
    _assert_same({0: got}, {0: want})
    assert len(calls) == 2


def test_a_range_ending_now_reads_only_the_windows_of_its_day_new_since_the_last(
    fleet, monkeypatch
):
    """The day still running (service day 5, from 02:00 UTC) read through the cache: a range
    ending later reads only the windows after those kept, one ending earlier none, one starting
    within the day all of its own; a late row or an override over the day has it read whole
    again; rows after the kept end change nothing. Every summary equals the one computed
    without the cache."""
    assert _build(fleet) == 12
    read: list[tuple] = []
    pair_data = pair_windows.pair_data

    def spied(session, pairs, *args):
        read.extend((c0, lo, hi) for c0, _, lo, hi in pairs)
        return pair_data(session, pairs, *args)

    monkeypatch.setattr(pair_windows, "pair_data", spied)
    cache = ReadCache(256)
    day_start = START + timedelta(days=5, hours=2)

    def at(minutes_after_start: int, hours: float = 24) -> list[tuple]:
        """The ranges read for a summary ending that long after the day's start, checked
        against the summary without the cache."""
        read.clear()
        end = day_start + timedelta(minutes=minutes_after_start)
        with fleet.transaction() as s:
            got = fleet_summary.summary(s, [], hours, end, cache)
        mine = sorted(read)
        with fleet.transaction() as s:
            _assert_same({0: got}, {0: fleet_summary.summary(s, [], hours, end)})
        return mine

    def ranges(a: int, b: int) -> list[tuple]:
        lo, hi = (day_start + timedelta(minutes=m) for m in (a, b))
        return [("X-A", lo, hi), ("Y-A", lo, hi)]

    assert at(120) == ranges(0, 120)  # the day so far, read whole
    assert at(90) == []  # before the kept end: nothing read
    assert at(180) == ranges(120, 180)  # only the new windows
    with fleet.transaction() as s:  # in order, after the kept end
        for cid in ("X-A", "X-B", "Y-A", "Y-B"):
            ingest(s, cid, [flat_row(START + timedelta(minutes=MINUTES + 1))])
    assert at(180, hours=30) == []
    # a range starting within the day is not kept: it starts elsewhere next time
    assert at(150, hours=2) == ranges(30, 150)
    assert at(180, hours=2.5) == ranges(30, 180)
    with fleet.transaction() as s:  # off the minute grid: counted nowhere, but late
        ingest(s, "X-B", [flat_row(day_start + timedelta(minutes=40, seconds=30))])
    assert at(150) == [ranges(0, 150)[0]]  # X read whole again, Y still kept
    with fleet.transaction() as s:
        s.add(_override("Y-A", day_start + timedelta(minutes=65), 20))
    assert at(150, hours=26) == [ranges(0, 150)[1]]


def test_the_scheduler_makes_them_a_few_at_a_time(fleet, small_predictor_file):
    settings = Settings(database_url=fleet.url, predictor_path=small_predictor_file)
    keeper = Scheduler(fleet, settings)
    assert keeper.keep_pair_days(max_days=5) == 5
    with fleet.transaction() as s:
        made = [d.day for d in s.query(PairDay)]
    # each day whose pair days were made has its fleet day, pooling those made
    assert {d: n for d, (n, _) in _fleet_days(fleet).items()} == {d: made.count(d) for d in made}
    assert keeper.keep_pair_days(max_days=100) == 7
    assert keeper.keep_pair_days() == 0
    with fleet.transaction() as s:
        assert s.query(PairDay).count() == 12
    assert [n for n, _ in _fleet_days(fleet).values()] == [2] * 6


def test_retention_drops_the_days_before_the_cutoff(fleet):
    assert _build(fleet) == 12
    with fleet.transaction() as s:
        assert fleet_days.build(s) == 6
    with fleet.transaction() as s:
        partitions.raw_retention(s, 2, START + timedelta(days=4))
    cutoff_window = pair_days.rollups.window_of(START + timedelta(days=2))
    with fleet.transaction() as s:
        assert min(d.first_window for d in s.query(PairDay)) > cutoff_window
        assert min(d.first_window for d in s.query(FleetDay)) > cutoff_window
    assert _build(fleet) == 2  # each pair's day the cutoff falls in, from its rollups
    got = _summaries(fleet)
    _assert_same(_figures(got), _comparisons(fleet, got))
