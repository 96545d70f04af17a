"""``bench service``: the service on PostgreSQL — telemetry ingest rows/s, the latency in ms of
the 24-h pair comparison and of the 24-h fleet summary with a month of fleet data stored, and the
live fleet's tick in s with its database writes.

- :mod:`.database` — the throw-away PostgreSQL database, plain SQL, binary COPY of telemetry
- :mod:`.fleet` — synthetic coaches and telemetry, users' tokens, the model file, the app
- :mod:`.ingest` — part 1, ingest through the API and ``commands.ingest`` against a plain INSERT
- :mod:`.comparison` — part 2, the pair comparison and the fleet summary with much and with
  little data stored
- :mod:`.tick` — part 3, the fleet tick with the database against the decisions in memory
- :mod:`.metrics_cost` — part 4, the Prometheus metrics' cost on the tick, on a request's
  latency (with against without, in the same run) and a scrape at the fleet's size
"""

from __future__ import annotations

from pathlib import Path

from trainclimate.bench.common import machine
from trainclimate.bench.service import comparison, ingest, metrics_cost, tick
from trainclimate.bench.service.database import (
    PG_SERVER,
    RESET,
    BenchDatabase,
    ServiceBenchError,
    postgres,
    sql,
)
from trainclimate.bench.service.fleet import model_file

__all__ = ["PG_SERVER", "ServiceBenchError", "run", "text"]

#: Rows of each ingest batch: an hour of 1-minute rows.
ROWS_PER_BATCH = 60
#: Ticks simulated before the timed ones, so the activated coaches have their lead-in (ρ).
LEAD_IN_TICKS = 14


def run(
    db_url: str | None = None,
    *,
    ingest_coaches: int = 50,
    ingest_batches: int = 12,
    trains: int = 50,
    days: int = 30,
    requests: int = 200,
    fleet: int = 1000,
    repeats: int = 1,
    progress=None,
) -> dict:
    """The service on PostgreSQL: telemetry ingest rows/s, the latency (ms) of the 24-h pair
    comparison and of the 24-h fleet summary with a month of fleet data stored, and the live
    fleet's tick (s) with its database writes.

    Runs on a fresh database created on the server ``$TRAINCLIMATE_TEST_PG_URL`` (default
    :data:`PG_SERVER`) and dropped at the end, or on the empty database ``db_url``, migrated with
    :func:`~trainclimate.service.store.db.migrate`; the app runs in-process (FastAPI's
    TestClient) with the cached default model, or a small one fitted here if there is none. Raises
    :class:`ServiceBenchError` if there is no such database. ``progress(1)`` after each of five
    stages.

    1. Ingest: ``ingest_coaches`` coaches × ``ingest_batches`` hourly batches of 60 rows through
       ``POST /api/v1/telemetry`` and through ``commands.ingest`` (one transaction per batch);
       baseline a plain SQLAlchemy executemany INSERT of the same batches. The three take turns
       batch by batch, each writing its own coaches.
    2. Comparison: ``trains`` × 2 coaches × ``days`` of 1-min rows loaded with binary COPY (the
       load rate is reported), then ``requests`` ``GET /api/v1/trains/{id}/comparison`` of random
       trains over random 24-h windows; baseline the same with 1 pair × 1 day stored (its own
       tables, in a schema of the same database), requests taking turns with the large one.
       Then as many ``GET /api/v1/fleet/summary?hours=24`` ending at random times (a new range
       each time: every pair summed), and as many over the last 24 h of the data (as the
       dashboard refreshes it: the pairs' windows kept), on both.
    3. Fleet tick: ``fleet`` live coaches (half activated), simulated minute by minute for a
       lead-in of 14 ticks; after a warm-up tick, ``repeats`` ticks of
       :meth:`~trainclimate.service.scheduler.Scheduler.tick_fleet` are timed; baseline the same
       decisions in memory on the same samples (the controller steps alone). The tick's parts
       are timed on their own as well: its telemetry reads, the samples' extraction, and a tick
       with no telemetry in its window (every coach stale: the claim and the writes).
    4. Metrics (:mod:`.metrics_cost`): their work in a tick of ``fleet`` coaches against the tick
       of part 3; ``requests`` requests of ``GET /health`` and ``GET /me`` with and without the
       observing middleware, taking turns; as many scrapes with ``fleet`` coaches tallied.
    """
    import tempfile

    step = progress or (lambda n: None)
    with tempfile.TemporaryDirectory(prefix="tc-bench-") as tmp, BenchDatabase(db_url) as url:
        model, model_kind = model_file(Path(tmp))
        server = postgres(url)
        ingested = ingest.run(url, model, ingest_coaches, ingest_batches, ROWS_PER_BATCH)
        step(1)
        compared = comparison.run(url, model, trains, days, requests, step)
        ticked = tick.run(url, model, fleet, LEAD_IN_TICKS, repeats)
        step(1)
        observed = metrics_cost.run(url, model, fleet, ticked["tick_s"], requests)
        step(1)
        if db_url is not None:
            sql(url, RESET)  # leave the given database as empty as it came
    return {
        "ingest": ingested,
        "comparison": compared,
        "fleet_tick": ticked,
        "metrics": observed,
        "target": {
            "fleet_tick_s": ticked["target_s"],
            "summary_p95_ms": compared["summary"]["target_p95_ms"],
        },
        "target_met": ticked["tick_s"] <= ticked["target_s"]
        and compared["summary"]["large"]["p95_ms"] <= compared["summary"]["target_p95_ms"],
        "model": model_kind,
        "database": {"created": db_url is None, **server},
        "machine": machine(),
    }


def text(d: dict) -> str:
    """Four lines: ingest rows/s three ways and the COPY rate; the comparison's and the fleet
    summary's latencies in ms with much and with little data stored; the fleet tick in s and its
    reasons."""
    i, c, t = d["ingest"], d["comparison"], d["fleet_tick"]
    large, small, summary = c["large"], c["small"], c["summary"]
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(t["reasons"].items()))
    return (
        f"ingest into PostgreSQL: HTTP API {i['http_rows_per_s']:,.0f} rows/s "
        f"({i['http_vs_plain']:.2f}× a plain INSERT), commands.ingest "
        f"{i['direct_rows_per_s']:,.0f} rows/s ({i['direct_vs_plain']:.2f}×), plain INSERT "
        f"{i['plain_insert_rows_per_s']:,.0f} rows/s; COPY {c['copy']['rows_per_s']:,.0f} rows/s\n"
        f"24-h comparison with {large['rows_stored'] / 1e6:.2f} M rows stored "
        f"({large['table']['total_mb']:,.0f} MB): median {large['median_ms']:.1f} ms, "
        f"p95 {large['p95_ms']:.1f} ms, p99 {large['p99_ms']:.1f} ms; with 1 pair × 1 day: "
        f"median {small['median_ms']:.1f} ms, p95 {small['p95_ms']:.1f} ms "
        f"(p95 ratio {c['p95_large_vs_small']:.2f}×)\n"
        f"24-h fleet summary of {summary['large']['trains_per_reply']} trains, same data stored, "
        f"as the dashboard refreshes it: median {summary['large']['median_ms']:.1f} ms, p95 "
        f"{summary['large']['p95_ms']:.1f} ms (target {summary['target_p95_ms']:g} ms; with 1 pair "
        f"× 1 day {summary['small']['p95_ms']:.1f} ms); a new range each time: median "
        f"{summary['new_range']['large']['median_ms']:.1f} ms, p95 "
        f"{summary['new_range']['large']['p95_ms']:.1f} ms\n"
        f"fleet tick of {t['coaches']} coaches with the database: {t['tick_s']:.2f} s "
        f"(target {t['target_s']:g} s); the decisions alone {t['controller_steps_s']:.2f} s "
        f"({t['tick_vs_steps']:.0f}×); reasons: {reasons}\n"
        f"{metrics_cost.text(d['metrics'])}"
    )
