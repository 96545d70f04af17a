"""Two ``serve`` replicas on one PostgreSQL database, three gateway emulators (two coaches each,
120×) posting to one of them, and ``kill -9`` of the other once both have decided ticks: no 5xx
and no failed post at the gateways, no (coach, tick) twice, no tick missing from the first to
the last, every telemetry minute stored, and the survivor deciding every tick after the kill."""

from __future__ import annotations

import json
import subprocess
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import func, select

from helpers.processes import CLI, token_cli
from helpers.service import wait_for
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import Setpoint, Telemetry
from trainclimate.sim import scenarios

TRAINS = ("124", "125", "126")
HOURS, SPEEDUP = 2.0, 120.0
PERIOD, MINUTE = timedelta(minutes=5), timedelta(minutes=1)


def decided_by(db: Database) -> dict[str, int]:
    """Setpoints per replica."""
    with db.transaction() as s:
        query = select(Setpoint.replica, func.count()).group_by(Setpoint.replica)
        return dict(s.execute(query).all())


def test_two_replicas_one_killed(db_url, servers, proc_env, tmp_path):
    if not db_url.startswith("postgresql"):
        pytest.skip("replicas share a PostgreSQL database (SQLite has no SKIP LOCKED)")
    migrate(db_url)
    env = {**proc_env, "TRAINCLIMATE_SCHEDULER_INTERVAL_S": "0.05"}
    survivor = servers(db_url, "--replica-name", "replica-1", env=env).start()
    victim = servers(db_url, "--replica-name", "replica-2", env=env).start()
    coaches = [f"{t}-{s}" for t in TRAINS for s in "AB"]
    token = token_cli(db_url, "gateway", proc_env, "--coaches", ",".join(coaches))
    gateways = []
    for t in TRAINS:
        args = [
            *CLI,
            "gateway",
            "--server",
            survivor.url,
            "--coaches",
            f"{t}-A,{t}-B",
            "--token",
            token,
            "--hours",
            str(HOURS),
            "--speedup",
            str(SPEEDUP),
            "--json",
        ]
        json_out, log = tmp_path / f"gateway-{t}.json", tmp_path / f"gw-{t}.log"
        with json_out.open("wb") as out, log.open("wb") as err:
            proc = subprocess.Popen(args, env=proc_env, stdout=out, stderr=err)
        gateways.append((proc, t))
    db = Database(db_url)
    try:
        # both replicas decide ticks (whichever loop claims a tick's coaches first) …
        wait_for(lambda: len(decided_by(db)) == 2, 60, "ticks decided by both replicas")
        victim.kill()
        killed_at = datetime.now(UTC)
        before = decided_by(db)
        for proc, t in gateways:
            assert proc.wait(timeout=180) == 0, (tmp_path / f"gw-{t}.log").read_text()[-2000:]
        with db.transaction() as s:
            rows = s.execute(
                select(Setpoint.coach_id, Setpoint.tick, Setpoint.replica, Setpoint.created_at)
            ).all()
            times = {c: sorted(s.scalars(select(Telemetry.time).where(Telemetry.coach_id == c)))
                     for c in coaches}  # fmt: skip
    finally:
        db.dispose()
        for proc, _ in gateways:
            if proc.poll() is None:
                proc.kill()
    # the gateways: every post stored, none failed (a 5xx or a connection error would count)
    for _, t in gateways:
        stats = json.loads((tmp_path / f"gateway-{t}.json").read_text())
        assert stats["failed_posts"] == 0 and stats["rows_unsent"] == 0, stats
        assert stats["rows_sent"] == 2 * stats["minutes"] == 2 * round(HOURS * 60)
    # telemetry complete at 1-minute resolution
    env0, _ = scenarios.build(scenarios.get("parked-heating-nov"), n_coaches=1, hours=HOURS)
    first = env0.time[0].to_pydatetime() + MINUTE
    expected = [first + i * MINUTE for i in range(round(HOURS * 60))]
    assert all(times[c] == expected for c in coaches)
    # one setpoint per coach and tick, no gap from the first tick to the last
    ticks: dict[str, list[datetime]] = {c: [] for c in coaches}
    for coach, tick, _, _ in rows:
        ticks[coach].append(tick)
    for coach, got in ticks.items():
        assert len(got) == len(set(got)), coach
        got.sort()
        assert got == [got[0] + i * PERIOD for i in range(len(got))], coach
        assert got[-1] >= expected[-1] - PERIOD, coach
    # both decided before the kill; after it, the survivor decided everything
    assert before.get("replica-1", 0) > 0 and before.get("replica-2", 0) > 0
    after = {r for _, _, r, made in rows if made > killed_at + timedelta(seconds=1)}
    assert after == {"replica-1"}
    print(f"decided before the kill {before}; setpoints in all {len(rows)}")
