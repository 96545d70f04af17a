"""``bench service``: the service on PostgreSQL — telemetry ingest rows/s, the latency in ms of
the fleet summary (6 h to 30 d) and of the pair comparison (24 h, 7 d) with ``--pairs`` ×
``--days`` of fleet data stored, and the live fleet's tick in s with its database writes.

- :mod:`.database` — the throw-away PostgreSQL database, plain SQL, binary COPY of telemetry
- :mod:`.fleet` — synthetic coaches and telemetry, users' tokens, the model file, the app
- :mod:`.ingest` — part 1, ingest through the API and ``commands.ingest`` against a plain INSERT
- :mod:`.comparison` — part 2, the fleet summary and the pair comparison at the fleet's scale,
  against the rollup floor
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
    pairs: int = 50,
    days: int = 30,
    samples: int = 30,
    requests: int = 200,
    fleet: int = 1000,
    repeats: int = 1,
    progress=None,
) -> dict:
    """The service on PostgreSQL: telemetry ingest rows/s, the fleet summary's and the pair
    comparison's latency (ms) with ``pairs`` × ``days`` of fleet data stored, and the live
    fleet's tick (s) with its database writes.

    Runs on a fresh database created on the server ``$TRAINCLIMATE_TEST_PG_URL`` (default
    :data:`PG_SERVER`) and dropped at the end, or on the empty database ``db_url``, migrated with
    :func:`~trainclimate.service.store.db.migrate`; the app runs in-process (FastAPI's
    TestClient) with the cached default model, or a small one fitted here if there is none. Raises
    :class:`ServiceBenchError` if there is no such database. ``progress(1)`` after each of five
    stages.

    1. Ingest (:mod:`.ingest`): ``ingest_coaches`` coaches × ``ingest_batches`` hourly batches
       of 60 rows through ``POST /api/v1/telemetry``, through ``commands.ingest`` (one
       transaction per batch) and through it without the window rollups; baseline a plain
       SQLAlchemy executemany INSERT of the same batches. They take turns batch by batch, each
       writing its own coaches.
    2. Fleet scale (:mod:`.comparison`): ``pairs`` × 2 coaches × ``days`` of 1-min rows loaded
       with binary COPY and their rollups and pair days built; ``samples`` requests per point of the
       fleet summary over 6 h, 24 h, 7 d and 30 d, refreshed, over new ranges and over the
       latest ranges (ending in the data's last windows, in the day still running), and of the
       pair comparison over 24 h and 7 d; baseline the rollup floor over the same windows.
    3. Fleet tick: ``fleet`` live coaches (half activated), simulated minute by minute for a
       lead-in of 14 ticks; after a warm-up tick, ``repeats`` ticks of
       :meth:`~trainclimate.service.scheduler.Scheduler.tick_fleet` are timed; baseline the same
       decisions in memory on the same samples (the controller steps alone). The tick's parts
       are timed on their own as well: its telemetry reads, the samples' extraction, and a tick
       with no telemetry in its window (every coach stale: the claim and the writes).
    4. Metrics (:mod:`.metrics_cost`): their work in a tick of ``fleet`` coaches against the tick
       of part 3; ``requests`` requests of ``GET /health`` and ``GET /me`` with and without the
       observing middleware, taking turns; as many scrapes with ``fleet`` coaches tallied.

    The result's ``summary_ms`` (window → ``refresh``/``new``/``latest`` → ``median``/``p95``),
    ``comparison_ms`` (window → ``median``/``p95``), ``ingest_rows_per_s`` (``commands.ingest``
    with the rollups) and ``rows`` (telemetry rows stored in part 2) gather the headline figures.
    """
    import tempfile

    step = progress or (lambda n: None)
    with tempfile.TemporaryDirectory(prefix="tc-bench-") as tmp, BenchDatabase(db_url) as url:
        model, model_kind = model_file(Path(tmp))
        server = postgres(url)
        ingested = ingest.run(url, model, ingest_coaches, ingest_batches, ROWS_PER_BATCH)
        step(1)
        scale = comparison.run(url, model, pairs, days, samples, step)
        ticked = tick.run(url, model, fleet, LEAD_IN_TICKS, repeats)
        step(1)
        observed = metrics_cost.run(url, model, fleet, ticked["tick_s"], requests)
        step(1)
        if db_url is not None:
            sql(url, RESET)  # leave the given database as empty as it came
    return {
        "summary_ms": {
            name: {kind: _mp(v[kind]) for kind in ("refresh", "new", "latest")}
            for name, v in scale["summary"].items()
        },
        "comparison_ms": {name: _mp(v) for name, v in scale["comparison"].items()},
        "ingest_rows_per_s": ingested["direct_rows_per_s"],
        "rows": scale["rows"],
        "ingest": ingested,
        "fleet_scale": scale,
        "fleet_tick": ticked,
        "metrics": observed,
        "target": {
            "fleet_tick_s": ticked["target_s"],
            "summary_p95_ms": comparison.SUMMARY_TARGET_P95_MS,
            "comparison_7d_p95_ms": comparison.COMPARISON_TARGET_P95_MS,
        },
        "target_met": ticked["tick_s"] <= ticked["target_s"] and comparison.met(scale),
        "model": model_kind,
        "database": {"created": db_url is None, **server},
        "machine": machine(),
    }


def _mp(latency: dict) -> dict:
    """``median`` and ``p95`` of a :func:`~trainclimate.bench.common.latency_ms`. [ms]"""
    return {"median": latency["median_ms"], "p95": latency["p95_ms"]}


def text(d: dict) -> str:
    """Ingest rows/s and what the rollups cost; the fleet summary's and the comparison's
    latencies per window against the rollup floor; the fleet tick in s and its reasons; the
    metrics' cost."""
    i, c, t = d["ingest"], d["fleet_scale"], d["fleet_tick"]
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(t["reasons"].items()))
    summary = "; ".join(
        f"{name} refresh {v['refresh']['median']:.0f}/{v['refresh']['p95']:.0f}, new "
        f"{v['new']['median']:.0f}/{v['new']['p95']:.0f}, latest "
        f"{v['latest']['median']:.0f}/{v['latest']['p95']:.0f} "
        f"(floor p95 {c['floor'][name]['p95_ms']:.1f})"
        for name, v in d["summary_ms"].items()
    )
    compared = "; ".join(
        f"{name} {v['median']:.0f}/{v['p95']:.0f}" for name, v in d["comparison_ms"].items()
    )
    return (
        f"ingest into PostgreSQL: HTTP API {i['http_rows_per_s']:,.0f} rows/s "
        f"({i['http_vs_plain']:.2f}× a plain INSERT), commands.ingest "
        f"{i['direct_rows_per_s']:,.0f} rows/s ({i['direct_vs_plain']:.2f}×; without the "
        f"rollups {i['direct_without_rollups_rows_per_s']:,.0f}, they cost "
        f"{100 * i['rollups_cost']:+.0f} %), plain INSERT {i['plain_insert_rows_per_s']:,.0f} "
        f"rows/s; COPY {c['copy']['rows_per_s']:,.0f} rows/s\n"
        f"{c['pairs']} pairs × {c['days']} days ({d['rows'] / 1e6:.1f} M rows, "
        f"{c['table']['total_mb']:,.0f} MB; rollups {c['rollups']['rows']:,} rows, "
        f"{c['rollups']['total_mb']:,.0f} MB, built in {c['rollups']['build_s']:.1f} s; "
        f"pair days {c['pair_days']['rows']:,} rows, {c['pair_days']['total_mb']:,.0f} MB, "
        f"built in {c['pair_days']['build_s']:.1f} s; fleet days {c['fleet_days']['rows']:,} "
        f"rows, built in {c['fleet_days']['build_s']:.1f} s)\n"
        f"fleet summary median/p95 ms: {summary}\n"
        f"pair comparison median/p95 ms: {compared}\n"
        f"fleet tick of {t['coaches']} coaches with the database: {t['tick_s']:.2f} s "
        f"(target {t['target_s']:g} s); the decisions alone {t['controller_steps_s']:.2f} s "
        f"({t['tick_vs_steps']:.0f}×); reasons: {reasons}\n"
        f"{metrics_cost.text(d['metrics'])}"
    )
