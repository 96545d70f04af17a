"""The read cache, on SQLite and on PostgreSQL: a coach's view and a pair comparison are served
from it while their data is unchanged, identical to a fresh computation, and computed afresh after
a new telemetry row, an override, its cancellation or a switch of the layer; and the cache itself
(bounded, one answer per key, errors not kept, simultaneous misses computed once)."""

from __future__ import annotations

import threading
import time
from datetime import datetime, timedelta

import pytest

from helpers.service import API, T0, at, decided, flat_rows, post_rows, register
from trainclimate.service.settings import Settings
from trainclimate.service.store import comparison as pair_comparison
from trainclimate.service.store import partitions, queries
from trainclimate.service.store.cache import ReadCache

RANGE = {"start": T0.isoformat(), "end": at(120).isoformat()}


@pytest.fixture
def settings(db_url, small_predictor_file) -> Settings:
    """The app's live loop runs once at start and then sleeps: no setpoint is issued while a test
    counts what the cache computes."""
    return Settings(
        database_url=db_url, predictor_path=small_predictor_file, scheduler_interval_s=3600
    )


@pytest.fixture
def computed(monkeypatch) -> dict[str, list]:
    """The coach views and comparisons computed (not served from the cache), as they happen."""
    calls: dict[str, list] = {"view": [], "comparison": []}
    view, comparison = queries.coach_view, pair_comparison.comparison

    def spy_view(session, coach, *args):
        calls["view"].append(coach.id)
        return view(session, coach, *args)

    def spy_comparison(session, train, *args):
        calls["comparison"].append(train.id)
        return comparison(session, train, *args)

    monkeypatch.setattr(queries, "coach_view", spy_view)
    monkeypatch.setattr(pair_comparison, "comparison", spy_comparison)
    return calls


def fresh(client, path: str, headers: dict, params: dict | None = None) -> dict:
    """The answer with the cache set aside: computed from the database as it is now."""
    cache = client.app.state.read_cache
    client.app.state.read_cache = ReadCache(0)
    try:
        reply = client.get(path, headers=headers, params=params)
    finally:
        client.app.state.read_cache = cache
    assert reply.status_code == 200
    return reply.json()


def get(client, path: str, headers: dict, params: dict | None = None):
    reply = client.get(path, headers=headers, params=params)
    assert reply.status_code == 200, reply.text
    return reply.json()


def test_a_comparison_is_fresh_after_new_telemetry_and_overrides(client, tokens, computed):
    op, viewer = tokens["operator"], tokens["viewer"]
    path = f"{API}/trains/P/comparison"
    register(client, op, "P-A", "P", active=True)
    register(client, op, "P-B", "P", active=False)
    decided(client, "P-A", 0, 115)
    decided(client, "P-B", 0, 115, "rule", "inactive")
    post_rows(client, op, "P-A", flat_rows(1, 60, power_kw=8.0))
    post_rows(client, op, "P-B", flat_rows(1, 60))

    first = get(client, path, viewer, RANGE)
    assert get(client, path, viewer, RANGE) == first == fresh(client, path, viewer, RANGE)
    assert len(computed["comparison"]) == 2  # the first request and the fresh one
    another_window = get(client, path, viewer, {**RANGE, "window_min": 60})
    assert another_window["window_min"] == 60 and len(computed["comparison"]) == 3

    # an override of the activated coach, from its clock (T0 + 60 min) for 30 min
    body = {"t_ref_c": 22.5, "duration_min": 30, "reason": "test"}
    assert client.post(f"{API}/coaches/P-A/override", json=body, headers=op).status_code == 201
    overridden = get(client, path, viewer, RANGE)
    assert len(computed["comparison"]) == 4
    assert overridden == fresh(client, path, viewer, RANGE)

    # new telemetry in the range: the next answer has it (and the override's window excluded)
    post_rows(client, op, "P-A", flat_rows(61, 120, power_kw=8.0))
    post_rows(client, op, "P-B", flat_rows(61, 120))
    later = get(client, path, viewer, RANGE)
    assert later != overridden and later == fresh(client, path, viewer, RANGE)
    excluded = {datetime.fromisoformat(w["start"]): w["excluded"] for w in later["windows"]}
    assert excluded[at(60)] is True and excluded[at(90)] is False
    n = len(computed["comparison"])
    assert get(client, path, viewer, RANGE) == later  # served again while nothing changes
    assert len(computed["comparison"]) == n

    # an override from the clock (T0 + 120 min) and its cancellation, in a range reaching past
    # the clock: each makes the next answer computed afresh
    wide = {**RANGE, "end": at(150).isoformat()}
    before = get(client, path, viewer, wide)
    assert client.post(f"{API}/coaches/P-B/override", json=body, headers=op).status_code == 201
    assert get(client, path, viewer, wide) == fresh(client, path, viewer, wide)
    assert client.delete(f"{API}/coaches/P-B/override", headers=op).status_code == 200
    assert get(client, path, viewer, wide) == fresh(client, path, viewer, wide) == before
    assert len(computed["comparison"]) == n + 5

    # the pair's roles now: with the layer off on both coaches, the answer says so
    switch = {"active": False, "reason": "test"}
    assert client.put(f"{API}/coaches/P-A/controller", json=switch, headers=op).status_code == 200
    both_off = get(client, path, viewer, RANGE)
    assert (both_off["activated"], both_off["deactivated"]) == (None, "P-A")
    assert both_off["windows"] == later["windows"]  # what ran in the past is unchanged


def test_a_coach_view_is_fresh_after_its_own_changes_only(client, tokens, computed):
    op, viewer = tokens["operator"], tokens["viewer"]
    for coach in ("A", "B"):
        register(client, op, coach, "T", active=coach == "A")
        post_rows(client, op, coach, flat_rows(1, 10))
    computed["view"].clear()  # registering answers with a view, computed

    fleet = get(client, f"{API}/coaches", viewer)
    assert computed["view"] == ["A", "B"]
    assert get(client, f"{API}/coaches", viewer) == fleet == fresh(client, f"{API}/coaches", viewer)
    assert get(client, f"{API}/coaches/A", viewer) == fleet[0]
    assert computed["view"] == ["A", "B", "A", "B"]  # the fresh list only

    # an override on A: A's view is computed again, B's is served
    body = {"t_ref_c": 21.0, "duration_min": 30, "reason": "test"}
    assert client.post(f"{API}/coaches/A/override", json=body, headers=op).status_code == 201
    computed["view"].clear()
    fleet = get(client, f"{API}/coaches", viewer)
    assert computed["view"] == ["A"] and fleet[0]["status"] == "override"
    assert fleet == fresh(client, f"{API}/coaches", viewer)

    # its cancellation, a new telemetry row of B, the layer switched off on A
    assert client.delete(f"{API}/coaches/A/override", headers=op).status_code == 200
    post_rows(client, op, "B", flat_rows(11, 11, t_room_mid_c=20.0))
    switch = {"active": False, "reason": "test"}
    assert client.put(f"{API}/coaches/A/controller", json=switch, headers=op).status_code == 200
    computed["view"].clear()
    fleet = get(client, f"{API}/coaches", viewer)
    assert sorted(computed["view"]) == ["A", "B"]
    assert fleet[0]["override_until"] is None and fleet[0]["ddpc_active"] is False
    assert fleet[1]["t_room_c"][1] == 20.0
    assert fleet == fresh(client, f"{API}/coaches", viewer)
    assert client.get(f"{API}/coaches/nope", headers=viewer).status_code == 404

    # the retention deletes every row, the newest included: both views are computed again
    with client.app.state.db.transaction() as s:
        partitions.raw_retention(s, 1, at(12) + timedelta(days=1))
    computed["view"].clear()
    fleet = get(client, f"{API}/coaches", viewer)
    assert sorted(computed["view"]) == ["A", "B"]
    assert [c["t_room_c"] for c in fleet] == [None, None]
    assert fleet == fresh(client, f"{API}/coaches", viewer)


# --- the cache itself ----------------------------------------------------------------------------
def test_the_cache_keeps_one_answer_per_key_and_at_most_size():
    cache = ReadCache(2)
    assert cache.get("a", 1, lambda: "a1") == "a1"
    assert cache.get("a", 1, lambda: "never") == "a1"
    assert cache.get("a", 2, lambda: "a2") == "a2"  # a new state replaces the answer
    assert cache.get("b", 1, lambda: "b1") == "b1"
    assert cache.get("a", 2, lambda: "never") == "a2"  # a used last: b goes first
    assert cache.get("c", 1, lambda: "c1") == "c1"
    assert len(cache) == 2
    assert cache.get("b", 1, lambda: "b1 again") == "b1 again"
    assert (cache.hits, cache.misses) == (2, 5)
    with pytest.raises(ValueError):
        cache.get("d", 1, lambda: int("x"))
    assert cache.get("d", 1, lambda: "d1") == "d1"  # an error is not kept
    assert ReadCache(0).get("a", 1, lambda: "computed") == "computed"


def test_a_peek_gives_the_answer_with_its_state_and_changes_nothing():
    cache = ReadCache(2)
    assert cache.peek("a") is None
    cache.put("a", 1, "a1")
    cache.put("b", 1, "b1")
    assert cache.peek("a") == (1, "a1")
    cache.put("c", 1, "c1")  # the peek did not make a the most recently used: it goes
    assert cache.peek("a") is None and cache.peek("b") == (1, "b1")
    # whether it holds an answer of a state, alike
    assert cache.holds("b", 1) and not cache.holds("b", 2) and not cache.holds("a", 1)
    assert (cache.hits, cache.misses) == (0, 0)


def test_simultaneous_misses_compute_once():
    cache = ReadCache(4)
    started, release = threading.Event(), threading.Event()
    calls = []

    def slow() -> str:
        calls.append(1)
        started.set()
        release.wait(10)
        return "answer"

    answers = []
    first = threading.Thread(target=lambda: answers.append(cache.get("k", 1, slow)))
    first.start()
    started.wait(10)
    others = [
        threading.Thread(target=lambda: answers.append(cache.get("k", 1, slow))) for _ in range(3)
    ]
    for t in others:
        t.start()
    time.sleep(0.2)  # the others in line for the first's answer (or, if late, served it kept)
    release.set()
    for t in (first, *others):
        t.join(10)
    assert answers == ["answer"] * 4 and calls == [1]
    assert (cache.hits, cache.misses) == (3, 1)
