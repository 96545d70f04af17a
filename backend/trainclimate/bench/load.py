"""``bench load``: the service under many concurrent clients, as a separate process.

``trainclimate serve --fleet demo --speedup 300`` is started as a child process (its own temporary
``$TRAINCLIMATE_HOME``, a free port, SQLite in that home or a throw-away PostgreSQL database), an
operator token is created with ``trainclimate token create``, and clients send a control room's
mix of requests over HTTP: the fleet list (``GET /api/v1/coaches``), pair comparisons
(``GET /api/v1/trains/{id}/comparison``, the last 24 h of the demo clock, as the dashboard asks)
and, one request in ten, an operator override (``POST /api/v1/coaches/{id}/override``, T_ref
within T_rule ± 1.5 K of the T_rule the fleet list last showed). Meanwhile the demo fleet runs at
300× real time: with the 5-min sampling period it issues one tick per coach per second of wall
time, and the setpoints issued during the run show whether the loop kept up.

The baseline, in the same run and on the same server just before the load: one client sending
the same mix in sequence — what a request costs when nobody else is asking.

When an MQTT broker answers (``--mqtt URL``, default the local Mosquitto on 127.0.0.1:1883), the
server also runs the MQTT feed (``serve --mqtt``, under a topic prefix of the run's own) and,
during the load, gateways publish the telemetry of live coaches through the broker
(:mod:`trainclimate.bench.mqtt_feed`), as trains do: the result says whether every row was stored
exactly once, how long the broker took to acknowledge, and whether the live loop kept ticking on
those coaches.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx

from trainclimate.bench.common import latency_ms, machine
from trainclimate.bench.mqtt_feed import MqttFeed, broker_at, mqtt_result, mqtt_text, register_live

API = "/api/v1"
#: How much faster than real time the demo fleet's clock runs.
SPEEDUP = 300.0
#: The controller's sampling period of ``serve`` (its default). [min]
SAMPLING_MIN = 5.0
#: Share of the requests that are operator overrides; the rest are half fleet lists, half pair
#: comparisons.
OVERRIDE_SHARE = 0.1
#: Overrides set T_ref within T_rule ± this (the API accepts ± 2 K; the margin covers T_rule
#: moving on between the fleet list a client read and its override). [K]
OVERRIDE_OFFSET_K = 1.5
#: A client gives up on a request after this long (an error, not a status). [s]
CLIENT_TIMEOUT_S = 60.0
#: How long the server may take to answer ``/api/v1/ready`` after its start. [s]
START_TIMEOUT_S = 120.0
#: The load's target: no 500, p99 at most this. [ms]
TARGET_P99_MS = 2000.0
#: The demo fleet may be this many ticks behind its clock at the end of the run and still be on
#: time (the two readings of the last tick can each miss one tick that is under way).
TICK_TOLERANCE = 2
#: The broker the MQTT gateways publish through by default (skipped if none answers there).
MQTT_URL = "mqtt://127.0.0.1:1883"
#: Live coaches fed over MQTT during the load (a gateway per pair).
MQTT_COACHES = 10


class LoadBenchError(Exception):
    """``bench load`` could not run: no database, or the server did not start (exit code 2)."""


def run(
    clients: int = 50,
    requests: int = 2000,
    db: str | None = None,
    *,
    baseline_requests: int | None = None,
    seed: int = 0,
    mqtt: str | None = MQTT_URL,
    mqtt_coaches: int = MQTT_COACHES,
    progress=None,
) -> dict:
    """The service under ``clients`` concurrent clients sending ``requests`` requests in all
    (see the module docstring), on SQLite or, with ``db`` a PostgreSQL URL, in a throw-away
    database created on that server and dropped at the end.

    Returns the load's ``requests``, ``by_status`` (counts per HTTP status), ``errors``
    (connection errors and time-outs, by kind), latency in ms over the answered requests
    (``median_ms``, ``p95_ms``, ``p99_ms``, ``max_ms``; also per kind of request), ``seconds``
    and ``requests_per_s``; ``baseline`` the same for one client in sequence
    (``baseline_requests``, default a tenth of ``requests``, at least 20) and the ratios of the
    median and p99; ``ticks`` (per coach: expected during the run from the wall time, issued
    from its setpoints, ``on_time``); ``target_met`` (no 500, no error, p99 ≤ 2 s, ticks on
    time); the database, the model and the machine (with its 1-min load average before and
    after: the clients share it with the server); ``mqtt`` (None when no broker answers at
    ``mqtt`` or ``mqtt_coaches`` is 0): ``mqtt_coaches`` live coaches fed through the broker
    during the load (:func:`~trainclimate.bench.mqtt_feed.mqtt_result`), and then the target
    also asks every row stored exactly once and their ticks on time. ``progress(1)`` after the
    start, the baseline and the load.
    """
    if clients < 1 or requests < 1:
        raise LoadBenchError("--clients and --requests must be ≥ 1")
    if mqtt_coaches < 0 or mqtt_coaches % 2:
        raise LoadBenchError("--mqtt-coaches must be an even number ≥ 0 (pairs)")
    broker = broker_at(mqtt, LoadBenchError) if mqtt_coaches else None
    step = progress or (lambda n: None)
    load_before = os.getloadavg()[0]
    n_baseline = baseline_requests or max(20, requests // 10)
    with tempfile.TemporaryDirectory(prefix="tc-load-") as tmp, _database(db, Path(tmp)) as url:
        from trainclimate.bench.service.fleet import model_file

        model, model_kind = model_file(Path(tmp))
        env = {**os.environ, "TRAINCLIMATE_HOME": str(Path(tmp) / "home")}
        env.pop("TRAINCLIMATE_DATABASE_URL", None)
        with _server(url, model, env, Path(tmp) / "server.log", broker) as base:
            token = _token(url, env, "operator")
            headers = {"Authorization": f"Bearer {token}"}
            fleet = _wait_for_fleet(base, headers)
            feed = None
            if broker is not None:
                live = [f"L{i // 2 + 1}-{'AB'[i % 2]}" for i in range(mqtt_coaches)]
                gateway = _token(url, env, "gateway", "--coaches", ",".join(live))
                register_live(base, gateway, live)
                start = datetime.now(UTC).replace(second=0, microsecond=0) - timedelta(days=1)
                feed = MqttFeed(broker, gateway, live, start, SPEEDUP, seed)
            step(1)
            baseline = asyncio.run(_load(base, headers, fleet, 1, n_baseline, seed))
            step(1)
            before = _last_ticks(base, headers, fleet["t_rule_c"])
            if feed is not None:
                feed.start()
            try:
                loaded = asyncio.run(_load(base, headers, fleet, clients, requests, seed + 1))
            finally:
                if feed is not None:
                    feed.stop()
            after = _last_ticks(base, headers, fleet["t_rule_c"])
            ticks = _ticks(base, headers, before, after)
            fed = (
                mqtt_result(base, headers, feed, SAMPLING_MIN, TICK_TOLERANCE)
                if feed is not None
                else None
            )
            step(1)
    errors = sum(loaded["errors"].values())
    target_met = (
        loaded["by_status"].get("500", 0) == 0
        and errors == 0
        and loaded["latency"]["p99_ms"] <= TARGET_P99_MS
        and ticks["on_time"]
        and (fed is None or (fed["exactly_once"] and fed["ticks"]["on_time"]))
    )
    return {
        "clients": clients,
        **loaded,
        "baseline": {
            **baseline,
            "median_ratio": loaded["latency"]["median_ms"] / baseline["latency"]["median_ms"],
            "p99_ratio": loaded["latency"]["p99_ms"] / baseline["latency"]["p99_ms"],
        },
        "ticks": ticks,
        "mqtt": fed,
        "target": {
            "no_500": True,
            "p99_ms": TARGET_P99_MS,
            "ticks_on_time": True,
            "mqtt_exactly_once": fed is not None,
        },
        "target_met": target_met,
        "database": "postgresql" if url.startswith("postgresql") else "sqlite",
        "model": model_kind,
        "machine": {
            **machine(),
            "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
        },
    }


# --- the database and the server -----------------------------------------------------------------
@contextmanager
def _database(server: str | None, tmp: Path):
    """A SQLite file in ``tmp``; or, for ``server`` a PostgreSQL URL, a new database on that
    server (dropped at the end)."""
    if server is None:
        yield f"sqlite:///{tmp / 'trainclimate.db'}"
        return
    import psycopg

    from trainclimate.bench.service.database import ServiceBenchError, libpq_url

    try:
        server = libpq_url(server)
    except ServiceBenchError:
        raise LoadBenchError(
            "--db takes a PostgreSQL server (a throw-away database is made on it); "
            "without --db the benchmark runs on SQLite"
        ) from None
    name = f"tc_load_{uuid.uuid4().hex[:10]}"
    try:
        with psycopg.connect(server, autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
    except psycopg.OperationalError as exc:
        first = (str(exc).strip() or type(exc).__name__).splitlines()[0]
        raise LoadBenchError(f"no PostgreSQL server to run on: {first}") from None
    try:
        yield f"{server.rsplit('/', 1)[0]}/{name}"
    finally:
        with psycopg.connect(server, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "trainclimate.cli", *args]


@contextmanager
def _server(url: str, model: Path, env: dict[str, str], log: Path, broker=None):
    """``trainclimate serve --fleet demo --speedup 300`` on ``url`` as a child process (with
    ``broker``, its MQTT feed under the broker's prefix), once it answers ``/api/v1/ready``: its
    base URL. Stopped (SIGTERM, then SIGKILL) at the end."""
    port = _free_port()
    args = _cli(
        "serve",
        "--fleet",
        "demo",
        "--speedup",
        f"{SPEEDUP:g}",
        "--db",
        url,
        "--port",
        str(port),
        "--predictor",
        str(model),
        "--log-level",
        "warning",
    )
    if broker is not None:
        prefix, client_id = broker.prefix, f"bench-service-{uuid.uuid4().hex[:10]}"
        args += ["--mqtt", broker.address, "--mqtt-prefix", prefix, "--mqtt-client-id", client_id]
    base = f"http://127.0.0.1:{port}"
    with log.open("wb") as out:
        proc = subprocess.Popen(args, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not _ready(base):
            if proc.poll() is not None or time.monotonic() > deadline:
                tail = log.read_text(errors="replace")[-2000:]
                raise LoadBenchError(f"the server did not start:\n{tail}")
            time.sleep(0.1)
        yield base
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


def _ready(base: str) -> bool:
    try:
        return httpx.get(f"{base}{API}/ready", timeout=2.0).status_code == 200
    except httpx.TransportError:
        return False


def _token(url: str, env: dict[str, str], role: str, *options: str) -> str:
    """A new token: ``trainclimate token create --role ROLE [OPTIONS…] --db URL --json``."""
    done = subprocess.run(
        _cli("token", "create", "--role", role, *options, "--db", url, "--json"),
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    if done.returncode != 0:
        raise LoadBenchError(f"token create failed: {done.stderr.strip()}")
    return json.loads(done.stdout)["token"]


def _wait_for_fleet(base: str, headers: dict) -> dict:
    """The demo fleet once every coach has had its first tick: {trains, T_rule per coach}."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        coaches = httpx.get(f"{base}{API}/coaches", headers=headers, timeout=10).json()
        if coaches and all(c["last_tick"] and c["t_rule_c"] is not None for c in coaches):
            break
        if time.monotonic() > deadline:
            raise LoadBenchError("the demo fleet issued no tick")
        time.sleep(0.2)
    trains = httpx.get(f"{base}{API}/trains", headers=headers, timeout=10).json()
    return {
        "trains": [t["id"] for t in trains],
        "t_rule_c": {c["id"]: c["t_rule_c"] for c in coaches},
    }


# --- the clients ---------------------------------------------------------------------------------
def _plan(n: int, seed: int, trains: list[str], coaches: list[str]) -> list[tuple]:
    """``n`` requests of the mix: (kind, path, override's coach and offset from T_rule in K)."""
    rng = random.Random(seed)
    plan: list[tuple[str, str, str | None, float]] = []
    for _ in range(n):
        draw = rng.random()
        if draw < OVERRIDE_SHARE:
            coach = rng.choice(coaches)
            offset = round(rng.uniform(-OVERRIDE_OFFSET_K, OVERRIDE_OFFSET_K), 1)
            plan.append(("override", f"{API}/coaches/{coach}/override", coach, offset))
        elif draw < OVERRIDE_SHARE + (1 - OVERRIDE_SHARE) / 2:
            plan.append(("fleet", f"{API}/coaches", None, 0.0))
        else:
            plan.append(("comparison", f"{API}/trains/{rng.choice(trains)}/comparison", None, 0.0))
    return plan


async def _load(base: str, headers: dict, fleet: dict, clients: int, n: int, seed: int) -> dict:
    """``n`` requests of :func:`_plan` sent by ``clients`` concurrent clients, each sending its
    next request when its last is answered: statuses, errors, latencies (ms), rate."""
    plan = _plan(n, seed, fleet["trains"], list(fleet["t_rule_c"]))
    t_rule = dict(fleet["t_rule_c"])  # the newest each client saw in a fleet list
    results: list[tuple[str, int | str, float]] = []
    queue = iter(plan)
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)

    async def client(http: httpx.AsyncClient) -> None:
        for kind, path, coach, offset in queue:
            t0 = time.perf_counter()
            try:
                if kind == "override":
                    body = {
                        "t_ref_c": round(t_rule[coach] + offset, 2),
                        "duration_min": 30,
                        "reason": "bench load",
                    }
                    reply = await http.post(path, json=body)
                else:
                    reply = await http.get(path)
            except httpx.TransportError as exc:
                results.append((kind, type(exc).__name__, time.perf_counter() - t0))
                continue
            results.append((kind, reply.status_code, time.perf_counter() - t0))
            if kind == "fleet" and reply.status_code == 200:
                t_rule.update({c["id"]: c["t_rule_c"] for c in reply.json()})

    async with httpx.AsyncClient(
        base_url=base, headers=headers, timeout=CLIENT_TIMEOUT_S, limits=limits
    ) as http:
        t0 = time.perf_counter()
        await asyncio.gather(*(client(http) for _ in range(clients)))
        seconds = time.perf_counter() - t0
    return _summary(results, seconds)


def _summary(results: list[tuple[str, int | str, float]], seconds: float) -> dict:
    """Counts per status and per error, latencies in ms of the answered requests, overall and
    per kind, and the rate."""
    by_status: dict[str, int] = {}
    errors: dict[str, int] = {}
    answered: dict[str, list[float]] = {}
    for kind, status, s in results:
        if isinstance(status, int):
            by_status[str(status)] = by_status.get(str(status), 0) + 1
            answered.setdefault(kind, []).append(s)
        else:
            errors[status] = errors.get(status, 0) + 1
    every = [s for kind in answered.values() for s in kind]
    return {
        "requests": len(results),
        "by_status": dict(sorted(by_status.items())),
        "errors": errors,
        "latency": latency_ms(every) if every else None,
        "by_kind": {kind: latency_ms(s) for kind, s in sorted(answered.items())},
        "seconds": seconds,
        "requests_per_s": len(results) / seconds,
    }


# --- the loop's ticks ----------------------------------------------------------------------------
def _last_ticks(base: str, headers: dict, demo: dict) -> tuple[float, dict[str, str]]:
    """The wall time (monotonic, s) and the last tick (ISO) of each coach of ``demo`` (the demo
    fleet's ids) as the fleet list shows."""
    coaches = httpx.get(f"{base}{API}/coaches", headers=headers, timeout=CLIENT_TIMEOUT_S).json()
    return time.monotonic(), {c["id"]: c["last_tick"] for c in coaches if c["id"] in demo}


def _ticks(base: str, headers: dict, before: tuple, after: tuple) -> dict:
    """Ticks issued per coach between the two readings of :func:`_last_ticks` (counted in its
    setpoints, ``GET /coaches/{id}/setpoints``), against those the demo clock should have
    produced in the wall time between them: one per ``SAMPLING_MIN × 60 / SPEEDUP`` s."""
    (w0, first), (w1, last) = before, after
    expected = (w1 - w0) * SPEEDUP / (SAMPLING_MIN * 60)
    issued = {}
    for coach, start in first.items():
        if last[coach] == start:
            issued[coach] = 0
            continue
        reply = httpx.get(
            f"{base}{API}/coaches/{coach}/setpoints",
            params={"start": start, "end": last[coach]},
            headers=headers,
            timeout=CLIENT_TIMEOUT_S,
        ).json()
        issued[coach] = len(reply["tick"])
    behind = expected - min(issued.values())
    return {
        "wall_s": w1 - w0,
        "expected": expected,
        "issued": issued,
        "behind_at_end": behind,
        "on_time": behind <= TICK_TOLERANCE,
    }


def text(d: dict) -> str:
    """Three lines: the load's statuses, latencies and rate; the baseline and the ratios; the
    ticks and the target; a fourth with the MQTT feed, when it ran."""
    lat, base = d["latency"], d["baseline"]
    statuses = ", ".join(f"{k} × {v}" for k, v in d["by_status"].items())
    errors = ", ".join(f"{k} × {v}" for k, v in d["errors"].items()) or "none"
    t = d["ticks"]
    return (
        f"{d['clients']} clients, {d['requests']} requests on {d['database']}: "
        f"p50 {lat['median_ms']:.0f} ms, p95 {lat['p95_ms']:.0f} ms, p99 {lat['p99_ms']:.0f} ms, "
        f"{d['requests_per_s']:.0f} requests/s; statuses {statuses}; errors {errors}\n"
        f"baseline, one client in sequence ({base['requests']} requests): "
        f"p50 {base['latency']['median_ms']:.0f} ms, p99 {base['latency']['p99_ms']:.0f} ms, "
        f"{base['requests_per_s']:.0f} requests/s; under load p50 {base['median_ratio']:.1f}×, "
        f"p99 {base['p99_ratio']:.1f}×\n"
        f"ticks per coach during the run: {t['expected']:.0f} expected, issued "
        f"{min(t['issued'].values())}–{max(t['issued'].values())} "
        f"({'on time' if t['on_time'] else 'behind'}); target (no 500, no error, p99 ≤ "
        f"{TARGET_P99_MS:.0f} ms, ticks on time): {'met' if d['target_met'] else 'missed'}"
    ) + (mqtt_text(d["mqtt"]) if d["mqtt"] else "")
