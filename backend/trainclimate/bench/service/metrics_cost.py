"""Part 4 of the service benchmark: what the Prometheus metrics cost (:mod:`trainclimate.service.
metrics`) — on the fleet tick, on a request's latency, and a scrape at the fleet's size.

- The tick: the metrics' own work in a tick of ``coaches`` coaches (:meth:`Metrics.tick` and
  :meth:`Metrics.decided` on its setpoint rows, every coach's latest decision changing), timed
  alone many times, against the tick measured in part 3: the tick with them over the tick
  without (the tick's run-to-run noise is larger than their cost, so timing two whole ticks would
  measure the noise).
- A request: ``GET /api/v1/health`` (the cheapest route: the largest relative cost) and
  ``GET /api/v1/me`` (a token check) through the app with its observing middleware
  (:class:`~trainclimate.service.api.observe.Observe`: request id, status counts, latency
  histogram) and through the same app without it, requests taking turns; medians and p95 (ms)
  and their ratios.
- A scrape: ``GET /api/v1/metrics`` with ``coaches`` coaches tallied (ms, bytes).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from trainclimate.bench.common import percentiles_ms

#: Sources and reasons of the coaches' decisions, as a fleet's tick has them (part 3's mix).
MIX = (("ddpc", "ok"), ("rule", "inactive"), ("rule", "warmup"), ("fallback", "stale"))


def _rows(coaches: int, turn: int) -> list[dict]:
    """A tick's setpoint rows: every coach's decision another of :data:`MIX` than last turn."""
    return [
        {
            "coach_id": f"M{i:05d}",
            "source": MIX[(i + turn) % 4][0],
            "reason": MIX[(i + turn) % 4][1],
        }
        for i in range(coaches)
    ]


def tick_cost(coaches: int, repeats: int = 50) -> dict:
    """The metrics' work in one tick of ``coaches`` coaches (s: median of ``repeats``)."""
    from trainclimate.service.metrics import Metrics

    metrics = Metrics("bench")
    turns = [_rows(coaches, turn) for turn in range(4)]
    metrics.decided("live", turns[0])
    seconds = []
    for j in range(repeats):
        t0 = time.perf_counter()
        metrics.decided("live", turns[(j + 1) % 4])
        metrics.tick("live", 1.0)
        seconds.append(time.perf_counter() - t0)
    return {"coaches": coaches, "metrics_s": float(np.median(seconds)), "repeats": repeats}


def _app(url: str, model: Path, observed: bool):
    """The app of part 1–3 (:func:`.fleet.app`), with or without its observing middleware."""
    from trainclimate.bench.service.fleet import app
    from trainclimate.service.api.observe import Observe

    application = app(url, model)
    if not observed:  # before the first request: the middleware stack is built then
        application.user_middleware = [
            m for m in application.user_middleware if m.cls is not Observe
        ]
    return application


def request_cost(url: str, model: Path, requests: int, coaches: int) -> dict:
    """Latency (ms) of ``requests`` requests of each route through the app with and without its
    observing middleware, taking turns; then ``requests`` scrapes with ``coaches`` tallied."""
    import warnings

    from trainclimate.bench.service.fleet import tokens

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Using `httpx` with `starlette.testclient`")
        from fastapi.testclient import TestClient

    with (
        TestClient(_app(url, model, True)) as with_,
        TestClient(_app(url, model, False)) as without,
    ):
        viewer, scraper = tokens(url, "viewer", "metrics")
        out = {}
        for name, path, headers in (
            ("health", "/api/v1/health", {}),
            ("me", "/api/v1/me", viewer),
        ):
            times: dict[str, list[float]] = {"with": [], "without": []}
            for client in (with_, without):  # warm-up
                for _ in range(20):
                    client.get(path, headers=headers)
            for _ in range(requests):
                for label, client in (("with", with_), ("without", without)):
                    t0 = time.perf_counter()
                    reply = client.get(path, headers=headers)
                    times[label].append(time.perf_counter() - t0)
                    assert reply.status_code == 200, reply.text
            assert "x-request-id" in with_.get(path, headers=headers).headers
            assert "x-request-id" not in without.get(path, headers=headers).headers
            figures = {}
            for label, seconds in times.items():
                p50, p95 = percentiles_ms(seconds)
                figures[label] = {"median_ms": p50, "p95_ms": p95}
            figures["median_ratio"] = figures["with"]["median_ms"] / figures["without"]["median_ms"]
            figures["p95_ratio"] = figures["with"]["p95_ms"] / figures["without"]["p95_ms"]
            out[name] = figures
        with_.app.state.metrics.decided("live", _rows(coaches, 0))
        scrape_s, size = [], 0
        for _ in range(requests):
            t0 = time.perf_counter()
            reply = with_.get("/api/v1/metrics", headers=scraper)
            scrape_s.append(time.perf_counter() - t0)
            size = len(reply.content)
        p50, p95 = percentiles_ms(scrape_s)
        out["scrape"] = {"coaches": coaches, "median_ms": p50, "p95_ms": p95, "bytes": size}
    return out


def run(url: str, model: Path, coaches: int, tick_s: float, requests: int = 300) -> dict:
    """Part 4 (see the module docstring); ``tick_s`` the tick of ``coaches`` coaches measured in
    part 3 (s)."""
    tick = tick_cost(coaches)
    tick["tick_s"] = tick_s
    tick["ratio"] = (tick_s + tick["metrics_s"]) / tick_s
    return {"tick": tick, **request_cost(url, model, requests, coaches)}


def text(d: dict) -> str:
    """One line: the tick's ratio, the requests' median ratios, the scrape."""
    t, h, m, s = d["tick"], d["health"], d["me"], d["scrape"]
    return (
        f"metrics: {t['metrics_s'] * 1e3:.2f} ms of a {t['tick_s']:.2f} s tick of {t['coaches']} "
        f"coaches ({t['ratio']:.4f}×); GET /health median {h['with']['median_ms']:.2f} ms with, "
        f"{h['without']['median_ms']:.2f} ms without ({h['median_ratio']:.2f}×), GET /me "
        f"{m['with']['median_ms']:.2f} / {m['without']['median_ms']:.2f} ms "
        f"({m['median_ratio']:.2f}×); a scrape at {s['coaches']} coaches median "
        f"{s['median_ms']:.1f} ms, p95 {s['p95_ms']:.1f} ms, {s['bytes'] / 1024:.1f} KiB"
    )
