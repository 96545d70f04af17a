"""Part 1 of the service benchmark: telemetry ingest rows/s through the HTTP API and through
``commands.ingest``, against a plain INSERT of the same batches."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from trainclimate.bench.common import latency_ms
from trainclimate.bench.service.database import RESET, sql
from trainclimate.bench.service.fleet import client as fleet_client
from trainclimate.bench.service.fleet import pair_ids, register, synthetic, tokens


def run(url: str, model: Path, coaches: int, batches: int, rows_per_batch: int) -> dict:
    """Telemetry ingest rows/s four ways on the same batches: the HTTP API, ``commands.ingest`` (one
    transaction per batch, no HTTP), the same without the window rollups kept and the pair days they
    change dropped (what that upkeep costs) and the baseline, a plain executemany INSERT per batch;
    interleaved batch by batch (each way writes its own coaches into one table), so a machine that
    slows down meanwhile slows all four alike. Then all rows once more in one executemany and one
    transaction. ``coaches`` coaches × ``batches`` hourly batches of ``rows_per_batch`` 1-minute
    rows; the HTTP requests' latencies in ms. Empties the tables afterwards."""
    from unittest import mock

    import pandas as pd
    from sqlalchemy import text

    from trainclimate.service.store import commands, pair_days, rollups
    from trainclimate.service.store.db import Database
    from trainclimate.service.store.models import Telemetry
    from trainclimate.service.store.telemetry import to_wire

    rng = np.random.default_rng(1)
    pairs = coaches // 2
    ids, train, active = pair_ids("H", pairs)
    start = pd.Timestamp("2024-11-01T00:00Z")
    batch_rows: list[tuple[int, list[dict]]] = []
    for b in range(batches):  # hourly batches, every coach's in turn (as gateways send them)
        minute = b * rows_per_batch + np.arange(1, rows_per_batch + 1)
        stamps = [t.to_pydatetime() for t in start + pd.to_timedelta(minute, unit="min")]
        for i in range(len(ids)):
            n = len(minute)
            v = synthetic(rng, np.full(n, train[i]), np.full(n, active[i]), minute)
            values = {c: a.tolist() for c, a in v.items()}
            rows = [
                {
                    "time": t,
                    **{c: values[c][k] for c in values},
                    "mode": "regular",
                    "connected": True,
                }
                for k, t in enumerate(stamps)
            ]
            batch_rows.append((i, rows))
    n_rows = sum(len(r) for _, r in batch_rows)
    way_ids = {
        way: pair_ids(prefix, pairs)[0]
        for way, prefix in zip(("http", "direct", "bare", "plain", "one"), "HDBPO", strict=True)
    }
    for way in way_ids.values():
        register(url, way, "live")
    bodies = [
        json.dumps(
            {
                "coach_id": way_ids["http"][i],
                "rows": [to_wire(r) for r in rows],
            }
        ).encode()
        for i, rows in batch_rows
    ]
    (operator,) = tokens(url, "operator")
    headers = {**operator, "Content-Type": "application/json"}
    db = Database(url)
    table = Telemetry.__table__
    plain_s = direct_s = bare_s = http_s = 0.0
    latencies = []
    with fleet_client(url, model) as client:
        for (i, rows), body in zip(batch_rows, bodies, strict=True):
            plain_rows = [{**r, "coach_id": way_ids["plain"][i]} for r in rows]
            t0 = time.perf_counter()  # the baseline: a plain INSERT of the batch
            with db.engine.begin() as conn:
                conn.execute(table.insert(), plain_rows)
            t1 = time.perf_counter()  # the command the API runs, without HTTP
            with db.transaction() as session:
                commands.ingest(session, way_ids["direct"][i], rows)
            t2 = time.perf_counter()  # through the HTTP API
            reply = client.post("/api/v1/telemetry", content=body, headers=headers)
            t3 = time.perf_counter()  # the command without the rollups and pair days' upkeep
            with (
                mock.patch.object(rollups, "add_rows"),
                mock.patch.object(pair_days, "forget"),
                db.transaction() as session,
            ):
                commands.ingest(session, way_ids["bare"][i], rows)
            t4 = time.perf_counter()
            if reply.status_code != 200 or reply.json()["stored"] != len(rows):
                raise RuntimeError(f"ingest failed: {reply.status_code} {reply.text[:200]}")
            plain_s += t1 - t0
            direct_s += t2 - t1
            http_s += t3 - t2
            bare_s += t4 - t3
            latencies.append(t3 - t2)
    every = [{**r, "coach_id": way_ids["one"][i]} for i, rows in batch_rows for r in rows]
    t0 = time.perf_counter()
    with db.engine.begin() as conn:
        conn.execute(table.insert(), every)
    one_s = time.perf_counter() - t0
    stored = sql(url, "SELECT count(*) FROM telemetry")[0][0]
    if stored != 5 * n_rows:
        raise RuntimeError(f"{stored} rows stored of {5 * n_rows}")
    with db.engine.begin() as conn:
        conn.execute(text(RESET))
    db.dispose()
    plain = n_rows / plain_s
    return {
        "rows": n_rows,
        "coaches": len(ids),
        "batches": len(batch_rows),
        "rows_per_batch": rows_per_batch,
        "http_rows_per_s": n_rows / http_s,
        "http_batch_latency": latency_ms(latencies),
        "direct_rows_per_s": n_rows / direct_s,
        "direct_without_rollups_rows_per_s": n_rows / bare_s,
        "rollups_cost": direct_s / bare_s - 1.0,
        "plain_insert_rows_per_s": plain,
        "plain_insert_one_transaction_rows_per_s": n_rows / one_s,
        "http_vs_plain": n_rows / http_s / plain,
        "direct_vs_plain": n_rows / direct_s / plain,
    }
