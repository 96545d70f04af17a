"""The gateway emulator through an outage: while the server is unreachable it backs off (after
each failed attempt it waits twice as long, 1 s, 2 s, 4 s … at most 60 s of wall time, keeping its
telemetry meanwhile, and tries at once again after a success); back online it catches up, its
backlog sent oldest first in batches the server takes, each row stored once."""

from __future__ import annotations

import itertools

import pytest

from helpers.processes import free_port, token_cli
from helpers.service import SIM_MINUTES, at, rows_per_minute, sim_rows
from trainclimate.service.adapters import gateway as gateway_module
from trainclimate.service.adapters.gateway import (
    BACKOFF_S,
    BATCH_BYTES,
    Batch,
    Gateway,
    first_batch,
)


def test_the_gateway_backs_off_exponentially_up_to_a_cap(monkeypatch):
    now = [1000.0]
    monkeypatch.setattr(gateway_module.time, "monotonic", lambda: now[0])
    url = f"http://127.0.0.1:{free_port()}"  # nothing listens there
    gw = Gateway(url, "tc_x", ["124-A", "124-B"], train_id="124", active=["124-A"], hours=7.0)
    attempts = []
    real_register = gw.register

    def register():
        attempts.append(now[0])
        return real_register()

    monkeypatch.setattr(gw, "register", register)
    for _ in range(400):  # 400 minutes of its clock, one wall second each
        gw.minute()
        now[0] += 1.0
    waits = [b - a for a, b in itertools.pairwise(attempts)]
    assert waits[:7] == [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 60.0]
    assert set(waits[7:]) == {BACKOFF_S[1]}
    assert sum(len(rows) for rows in gw.buffer.values()) == 2 * 400  # every row kept
    # after a success the next failure waits the shortest again
    gw._reachable()
    gw._unreachable()
    assert gw._retry_at == now[0] + BACKOFF_S[0]


# --- catching up after an outage -----------------------------------------------------------
#: Five days of minutes: what a gateway keeps through five days offline, per coach.
FIVE_DAYS = 5 * 24 * 60


def backlog(coach: int, minutes: int) -> list[dict]:
    """``minutes`` rows of simulated coach ``coach`` (its two simulated hours over and over),
    stamped minute by minute up to ``T0``: what the gateway kept before its clock's start."""
    rows = sim_rows(coach, 1, SIM_MINUTES)
    return [{**rows[k % SIM_MINUTES], "time": at(k - minutes + 1)} for k in range(minutes)]


@pytest.mark.parametrize("limit", [None, 300_000], ids=["default-limit", "300kB-limit"])
def test_a_gateway_offline_for_five_days_catches_up(limit, servers, proc_env, tmp_path):
    """Back after five days offline (7 200 rows per coach, 2.7 MB: one POST would be over the
    server's 2 MiB body limit, 413 every time), the gateway sends its backlog oldest first in
    batches under the limit — halving them after a 413 when the server's limit is lower — and
    every minute of both coaches is stored exactly once."""
    db_url = f"sqlite:///{tmp_path / 'trainclimate.db'}"
    env = {**proc_env, **({"TRAINCLIMATE_MAX_BODY_BYTES": str(limit)} if limit else {})}
    server = servers(db_url, env=env).start()
    token = token_cli(db_url, "gateway", proc_env, "--coaches", "124-A,124-B")
    ids = ["124-A", "124-B"]
    gw = Gateway(server.url, token, ids, train_id="124", active=["124-A"], hours=1.0, timeout_s=30)
    assert gw.register()
    for coach, cid in enumerate(ids):
        gw.buffer[cid] = backlog(coach, FIVE_DAYS)
    sent: dict[str, list[Batch]] = {cid: [] for cid in ids}
    send = gw.link.send

    def recorded(cid: str, batch: Batch) -> None:
        send(cid, batch)
        sent[cid].append(batch)

    gw.link.send = recorded
    for _ in range(3):  # back online: three minutes of its clock
        gw.minute()
    gw._flush()
    assert gw.stats.rows_unsent == 0 and gw.stats.rows_sent == 2 * (FIVE_DAYS + 3)
    for cid in ids:
        throughs = [b.through for b in sent[cid]]
        assert throughs == sorted(throughs) and len(set(throughs)) == len(throughs)  # oldest first
        assert all(sum(len(r) + 1 for r in b.rows) <= BATCH_BYTES for b in sent[cid])
        assert len(sent[cid]) >= 3
    expected = {(cid, at(m)) for cid in ids for m in range(-FIVE_DAYS + 1, 4)}
    stored = rows_per_minute(db_url)
    assert set(stored) == expected and set(stored.values()) == {1}


def test_a_batch_is_the_oldest_rows_that_fit():
    rows = sim_rows(0, 1, 10)
    one = len(first_batch(rows, 10**6, 10**4).rows[0]) + 1
    assert len(first_batch(rows, 10**6, 10**4).rows) == 10
    assert first_batch(rows, 10**6, 4).through == at(4)
    assert first_batch(rows, 3 * one, 10**4).through == at(3)
    assert len(first_batch(rows, 1, 10**4).rows) == 1  # at least one row
