"""Part 2 of the service benchmark: the latency (ms) of a 24-h pair comparison and of the 24-h
fleet summary with a month of fleet data stored, each against the same with one pair × one day
stored; the COPY load rate."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from trainclimate.bench.common import latency_ms
from trainclimate.bench.service.database import (
    copy_block,
    copy_telemetry,
    in_schema,
    sql,
    table_size,
)
from trainclimate.bench.service.fleet import client as fleet_client
from trainclimate.bench.service.fleet import pair_ids, register, synthetic, tokens

#: The fleet summary's goal: p95 over 24 h of 100 coaches with 30 days stored, as the dashboard
#: refreshes it. [ms]
SUMMARY_TARGET_P95_MS = 150.0
#: The first stored minute of the synthetic data.
DATA_START = pd.Timestamp("2024-11-01T00:00Z")


def run(url: str, model: Path, trains: int, days: int, requests: int, progress) -> dict:
    """p95 latency (ms) of a 24-h pair comparison and of the 24-h fleet summary with ``trains``
    pairs × ``days`` stored, against the same with 1 pair × 1 day stored (its own tables, in
    schema ``bench_small`` of the same database), ``requests`` requests of each taking turns;
    the COPY load rate of the large data set (rows/s, MB sent, s for VACUUM ANALYZE).
    ``progress(1)`` after the load and after the requests."""
    from trainclimate.service.store.db import migrate

    small_url = in_schema(url, "bench_small")
    sql(url, "CREATE SCHEMA bench_small")
    try:
        migrate(small_url)
        register(small_url, pair_ids("C", 1)[0], "archive")
        copy_telemetry(small_url, _rows(1, 1, seed=2))
        sql(small_url, "VACUUM ANALYZE telemetry", autocommit=True)

        ids = pair_ids("C", trains)[0]
        register(url, ids, "archive")  # not the live fleet: the tick later leaves them alone
        n_rows = len(ids) * days * 1440
        sent, copy_s = copy_telemetry(url, _rows(trains, days, seed=2))
        t0 = time.perf_counter()
        sql(url, "VACUUM ANALYZE telemetry", autocommit=True)
        vacuum_s = time.perf_counter() - t0
        if progress:
            progress(1)
        databases = {"large": (url, trains, days), "small": (small_url, 1, 1)}
        timed = _time_requests(model, databases, requests, _comparison, "windows", seed=3)
        summary = _time_requests(model, databases, requests, _summary, "trains", seed=4)
        refresh = _time_requests(model, databases, requests, _refresh, "trains", seed=5)
        large, small = timed["large"], timed["small"]
        large["rows_stored"], large["table"] = n_rows, table_size(url)
        small["rows_stored"], small["table"] = 2 * 1440, table_size(small_url)
        if progress:
            progress(1)
    finally:
        sql(url, "DROP SCHEMA IF EXISTS bench_small CASCADE")
    return {
        "coaches": len(ids),
        "days": days,
        "window_hours": 24,
        "large": large,
        "small": small,
        "p95_large_vs_small": large["p95_ms"] / small["p95_ms"],
        "median_large_vs_small": large["median_ms"] / small["median_ms"],
        "summary": {
            **refresh,
            "p95_large_vs_small": refresh["large"]["p95_ms"] / refresh["small"]["p95_ms"],
            "target_p95_ms": SUMMARY_TARGET_P95_MS,
            "new_range": {
                **summary,
                "p95_large_vs_small": summary["large"]["p95_ms"] / summary["small"]["p95_ms"],
            },
        },
        "copy": {
            "rows": n_rows,
            "seconds": copy_s,
            "rows_per_s": n_rows / copy_s,
            "mb_sent": sent / 2**20,
            "vacuum_analyze_s": vacuum_s,
        },
    }


def _rows(trains: int, days: int, seed: int):
    """Blocks for :func:`~.database.copy_telemetry`: ``trains`` pairs × ``days`` of 1-minute
    rows, one block per day, in the order a live feed stores them (hour by hour, coach after
    coach)."""
    ids, train, active = pair_ids("C", trains)
    start_s = DATA_START.timestamp()
    rng = np.random.default_rng(seed)
    hour, coach, minute = np.meshgrid(
        np.arange(24), np.arange(len(ids)), np.arange(1, 61), indexing="ij"
    )
    coach, day_minute = coach.ravel(), (hour * 60 + minute).ravel()
    id_array = np.asarray(ids, dtype="S")[coach]
    for day in range(days):
        m = day * 1440 + day_minute
        v = synthetic(rng, train[coach], active[coach], m)
        yield copy_block(id_array, start_s + 60.0 * m, v)


def _comparison(rng, trains: int, days: int, first) -> tuple[str, dict]:
    """A random train's pair comparison over the 24 h from ``first``."""
    end = first + pd.Timedelta(hours=24)
    train = f"C{int(rng.integers(trains)):03d}"
    return f"/api/v1/trains/{train}/comparison", {
        "start": first.isoformat(),
        "end": end.isoformat(),
    }


def _summary(rng, trains: int, days: int, first) -> tuple[str, dict]:
    """The fleet summary over the 24 h from ``first``."""
    return "/api/v1/fleet/summary", {
        "hours": 24,
        "end": (first + pd.Timedelta(hours=24)).isoformat(),
    }


def _refresh(rng, trains: int, days: int, first) -> tuple[str, dict]:
    """The fleet summary over the last 24 h of the data, as the dashboard asks for it again and
    again (its windows kept while unchanged)."""
    end = DATA_START + pd.Timedelta(days=days)
    return "/api/v1/fleet/summary", {"hours": 24, "end": end.isoformat()}


def _time_requests(model: Path, databases: dict, n: int, request, items: str, seed: int) -> dict:
    """``n`` GETs ``request(rng, trains, days, first)`` → (path, params) on each of ``databases``
    (name → (URL, trains, days)), taking turns request by request, each over a random 24-h
    window from ``first`` (after a few untimed ones): latency per database in ms, and the
    length of the reply's list ``items`` (``<items>_per_reply``)."""
    import contextlib

    rng = np.random.default_rng(seed)
    start = DATA_START
    latencies: dict[str, list[float]] = {name: [] for name in databases}
    windows: dict[str, int] = {}
    with contextlib.ExitStack() as stack:
        clients = {
            name: (stack.enter_context(fleet_client(url, model)), tokens(url, "viewer")[0])
            for name, (url, _, _) in databases.items()
        }
        for i in range(n + 5):
            for name, (_, trains, days) in databases.items():
                client, viewer = clients[name]
                first = start + pd.Timedelta(minutes=int(rng.integers(0, (days - 1) * 1440 + 1)))
                path, params = request(rng, trains, days, first)
                t0 = time.perf_counter()
                reply = client.get(path, params=params, headers=viewer)
                elapsed = time.perf_counter() - t0
                if reply.status_code != 200:
                    raise RuntimeError(f"{path} failed: {reply.status_code} {reply.text[:200]}")
                if i >= 5:
                    latencies[name].append(elapsed)
                    windows[name] = len(reply.json()[items])
    return {
        name: {**latency_ms(latencies[name]), f"{items}_per_reply": windows[name]}
        for name in databases
    }
