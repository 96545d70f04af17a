"""A paused replica does not freeze the fleet: two ``serve`` replicas on one PostgreSQL database,
two gateway emulators (two coaches each, 60×: a period is 5 s) posting to one of them, and the
other paused (SIGSTOP) right in a tick, holding the locks on the coaches it claimed — as a GC
pause, a VM migration or a stuck disk would. For the 15 s of the pause (three periods, longer
than a setpoint's validity) the running replica keeps storing every gateway's rows, answers a
post within a few seconds, ``/health`` at once and ``/ready`` within its timeout, and keeps
ticking every coach with at most one tick skipped (the server ends the paused replica's idle
transaction after 2 s here, ``db_idle_in_transaction_s``, and its locks with it). Resumed
(SIGCONT), the paused replica commits nothing it decided before the pause, and neither replica
serves a setpoint whose validity has run out on its coach's clock."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import time
from datetime import UTC, datetime, timedelta

import httpx
import pytest
from sqlalchemy import func, select, text

from helpers.processes import CLI, token_cli
from helpers.service import flat_row, to_wire, wait_for
from trainclimate.service.store import liveness
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import Setpoint, Telemetry

SPEEDUP = 60.0
PERIOD = timedelta(minutes=5)
PERIOD_WALL_S = 300 / SPEEDUP
PAUSE_S = 15.0
COACHES = ["124-A", "124-B", "125-A", "125-B"]
#: what the paused replica's claim of a tick looks like: its transaction holds the row locks
#: of ``SELECT … FOR NO KEY UPDATE`` on ``coaches`` (a RowShareLock on the table)
CLAIMING = text(
    "SELECT a.pid FROM pg_stat_activity a JOIN pg_locks l ON l.pid = a.pid "
    "JOIN pg_class c ON c.oid = l.relation WHERE a.application_name = :app "
    "AND c.relname = 'coaches' AND l.mode = 'RowShareLock' AND l.granted"
)


def ticks(db: Database) -> dict[str, list[tuple[datetime, str, datetime]]]:
    """Every coach's (tick, replica, created_at), by tick."""
    with db.transaction() as s:
        rows = s.execute(
            select(Setpoint.coach_id, Setpoint.tick, Setpoint.replica, Setpoint.created_at)
        ).all()
    out: dict[str, list] = {c: [] for c in COACHES}
    for coach, tick, replica, made in rows:
        if coach in out:
            out[coach].append((tick, replica, made))
    return {c: sorted(v) for c, v in out.items()}


def stored(db: Database) -> int:
    with db.transaction() as s:
        return s.scalar(select(func.count()).select_from(Telemetry))


def pause_in_a_tick(db: Database, pid: int, app: str, tries: int = 200) -> None:
    """SIGSTOP ``pid`` while its database session (``app``) holds a tick's claim: poll for the
    claim, stop the process, and check the claim is still held (else resume and try again)."""
    with db.engine.connect() as conn:
        for _ in range(tries):
            deadline = time.monotonic() + 10
            while not conn.execute(CLAIMING, {"app": app}).first():
                conn.rollback()
                assert time.monotonic() < deadline, "the replica claims no tick"
                time.sleep(0.002)
            os.kill(pid, signal.SIGSTOP)
            conn.rollback()
            if conn.execute(CLAIMING, {"app": app}).first():
                conn.rollback()
                return
            os.kill(pid, signal.SIGCONT)  # it committed just before: again
            conn.rollback()
    pytest.fail("could not pause the replica inside a tick")


def test_a_paused_replica_does_not_freeze_the_fleet(db_url, servers, proc_env, tmp_path):
    if not db_url.startswith("postgresql"):
        pytest.skip("replicas share a PostgreSQL database (SQLite has no SKIP LOCKED)")
    migrate(db_url)
    env = {
        **proc_env,
        "TRAINCLIMATE_SCHEDULER_INTERVAL_S": "0.05",
        "TRAINCLIMATE_DB_IDLE_IN_TRANSACTION_S": "2",
    }
    running = servers(db_url, "--replica-name", "replica-1", env=env).start()
    paused = servers(db_url, "--replica-name", "replica-2", env=env).start()
    token = token_cli(db_url, "gateway", proc_env, "--coaches", ",".join([*COACHES, "X"]))
    gateway = {"Authorization": f"Bearer {token}"}
    gateways = []
    for t in ("124", "125"):
        args = [*CLI, "gateway", "--server", running.url, "--coaches", f"{t}-A,{t}-B",
                "--token", token, "--hours", "2", "--speedup", str(SPEEDUP)]  # fmt: skip
        with (tmp_path / f"gw-{t}.log").open("wb") as log:
            gateways.append(subprocess.Popen(args, env=proc_env, stdout=log, stderr=log))
    body = {"id": "X", "train_id": "X", "ddpc_active": False}
    assert httpx.post(f"{running.url}/api/v1/coaches", json=body, headers=gateway).is_success
    db = Database(db_url)
    t0 = time.monotonic()
    try:
        # both replicas decide ticks, then replica-2 is paused in one
        wait_for(
            lambda: {r for v in ticks(db).values() for _, r, _ in v} == {"replica-1", "replica-2"},
            60,
            "ticks decided by both replicas",
        )
        print(f"both replicas ticking after {time.monotonic() - t0:.1f} s")
        pause_in_a_tick(db, paused.proc.pid, "trainclimate:replica-2")
        paused_at = datetime.now(UTC)
        rows_at_pause = stored(db)
        latencies, health_s, ready_s = [], [], []
        started = time.monotonic()
        while time.monotonic() - started < PAUSE_S:
            row = to_wire(flat_row(datetime.now(UTC).replace(microsecond=0)))
            t = time.monotonic()
            reply = httpx.post(
                f"{running.url}/api/v1/telemetry",
                json={"coach_id": "X", "rows": [row]},
                headers=gateway,
                timeout=30,
            )
            latencies.append(time.monotonic() - t)
            assert reply.status_code == 200, reply.text
            t = time.monotonic()
            assert httpx.get(f"{running.url}/api/v1/health", timeout=30).status_code == 200
            health_s.append(time.monotonic() - t)
            t = time.monotonic()
            httpx.get(f"{running.url}/api/v1/ready", timeout=30)
            ready_s.append(time.monotonic() - t)
            time.sleep(0.5)
        during = ticks(db)
        rows_in_pause = stored(db) - rows_at_pause
        os.kill(paused.proc.pid, signal.SIGCONT)
        resumed_at = datetime.now(UTC)
        time.sleep(3)
        # no expired setpoint served, by either replica: each valid on its coach's clock now
        with db.transaction() as s:
            clocks = {c: r.time for c, r in liveness.clocks(s).items()}
        for server in (running, paused):
            for coach in COACHES:
                sp = httpx.get(
                    f"{server.url}/api/v1/coaches/{coach}/setpoint", headers=gateway, timeout=10
                ).json()
                assert sp["valid_until"] is None or (
                    datetime.fromisoformat(sp["valid_until"]) > clocks[coach]
                ), (server.url, sp, clocks[coach])
        after = ticks(db)
    finally:
        db.dispose()
        for proc in gateways:
            proc.kill()
    # ingest went on: posts answered within a few seconds, the gateways' rows kept arriving
    assert max(latencies) < 3.0, latencies
    assert max(health_s) < 1.0, health_s
    assert max(ready_s) < 5.0, ready_s
    minutes_in_pause = PAUSE_S * SPEEDUP / 60  # per coach, at 60×
    assert rows_in_pause >= 0.8 * len(COACHES) * minutes_in_pause, rows_in_pause
    # ticks went on for every coach during the pause, at most one skipped
    for coach in COACHES:
        in_pause = [tick for tick, _, made in during[coach] if made > paused_at]
        assert len(in_pause) >= PAUSE_S / PERIOD_WALL_S - 2, (coach, during[coach])
        got = [tick for tick, _, _ in after[coach]]
        gaps = [b - a for a, b in itertools.pairwise(got)]
        assert max(gaps) <= 2 * PERIOD, (coach, got)
    # the paused replica committed nothing it decided before the pause once resumed: every
    # setpoint it decided before the resumption was stored before it
    late = [
        (c, tick, made)
        for c, v in after.items()
        for tick, replica, made in v
        if replica == "replica-2" and made < resumed_at and (tick, replica, made) not in during[c]
    ]
    assert late == [], late
    # its session was ended by the server (the message depends on where it was waiting), which
    # it logs when its thread next uses the session: on a busy machine, after the checks above
    ended = ("idle-in-transaction timeout", "server closed the connection")
    wait_for(
        lambda: any(m in paused.log.read_text(errors="replace") for m in ended),
        30,
        "the paused replica's log of its session ended by the server",
    )
