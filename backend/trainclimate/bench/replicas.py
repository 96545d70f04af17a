"""``bench replicas``: one tick of a live fleet decided by one and by two service processes
("replicas") sharing one PostgreSQL database.

A throw-away database is created on the PostgreSQL server ``--db`` names (default
``$TRAINCLIMATE_TEST_PG_URL``, else :data:`~trainclimate.bench.service.database.PG_SERVER`) and
dropped at the end. In it: ``--coaches`` live coaches (default 10 000; coach A of each train
activated, B not) of ``parked-heating-nov``, simulated minute by minute and loaded with binary COPY
(:func:`~trainclimate.bench.service.tick.live_fleet`), and the benchmark's model registered.

Then, for P = 1 and P = 2, P child processes (:func:`run_replica`, real OS processes started
together) each build ``Scheduler(Database(url), Settings(..., replica_name="bench-replica-i"))``
as a service replica does, and at each tick all of them call ``tick_fleet("live", tick)`` at the
same moment (a start time their parent sends them): they claim the coaches in batches of 250 per
transaction with ``SELECT … FOR UPDATE SKIP LOCKED``, so they split the fleet between them. Two
warm-up ticks (the controllers, the engine's connections; with SKIP LOCKED a process may take
other coaches at each tick, hence two), then three measured ticks: a tick's time is from the
common start to the moment the last process finished; the median of the three is reported.
Both numbers of processes decide the same five ticks on the same telemetry: before each run the
setpoints and their rollups are deleted and the coaches' ``last_tick`` and ``held_by`` reset (the
decisions' cost depends on the data: later ticks of the scenario, nearer sunrise, take the solver
longer).

Each process reports per tick the coaches it issued, its own time, its CPU time, the time in
the database (every cursor execute, timed with SQLAlchemy's ``before_cursor_execute`` and
``after_cursor_execute`` events; the commits on their own) and the tick's parts, timed where the
scheduler calls them: the telemetry reads (``load_rows``), the samples
(``controller_samples``), the decisions (``Scheduler.decide``: DDPC steps and rule setpoints) and
the rest (the claim, the overrides, the setpoints' insert, the ``last_tick`` updates, the
commits), and the controllers it built (one per activated coach new to the process). After each
tick the database is checked: every coach has exactly one setpoint for it, how many each replica
decided (``setpoints.replica``), and how many coaches another replica decided than at the
previous tick, with the DDPC step times of those and of the others. The machine's CPU time over
the tick (``/proc/stat``) against the processes' own shows what the PostgreSQL server took of the
cores.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from contextlib import ExitStack
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from trainclimate.bench.common import machine, start_child

#: The numbers of service processes the tick is measured with.
PROCESSES = (1, 2)
#: Unmeasured ticks before the measured ones, every process taking part.
WARM_UP_TICKS = 2
#: Measured ticks per number of processes (their median is reported).
MEASURED_TICKS = 3
#: Coaches a scheduler claims per transaction (``Scheduler.tick_fleet``'s default).
BATCH = 250
#: The targets: a tick of 10 000 coaches by 2 processes in at most this long (s)…
TARGET_TICK_S = 10.0
#: … and at least this many times faster than by 1 process.
TARGET_SPEEDUP = 1.6
#: The processes start a tick this long after their parent sends them its start time. [s]
START_DELAY_S = 0.2
#: The parts of a tick each process times (s): the functions the scheduler calls (the
#: controllers' construction within the decisions), the database time (cursor executes; those
#: within the telemetry reads also on their own) and the commits.
PARTS = (
    "telemetry_read",
    "database_in_telemetry_read",
    "samples",
    "decisions",
    "controller_builds",
    "database",
    "database_commit",
)


class ReplicasBenchError(Exception):
    """``bench replicas`` could not run: no PostgreSQL server, bad arguments (exit code 2)."""


def run(coaches: int = 10_000, db: str | None = None, *, batch: int = BATCH, progress=None) -> dict:
    """One tick of ``coaches`` live coaches by 1 and by 2 service processes (see the module
    docstring), on a throw-away database on the PostgreSQL server ``db``; ``batch`` coaches
    claimed per transaction. Raises :class:`ReplicasBenchError` without a PostgreSQL server.
    ``progress(1)`` after the set-up and after each number of processes.

    Returns ``coaches``; ``tick_s`` per number of processes ("1", "2": the median of the measured
    ticks, s) and ``tick_s_runs`` (every measured tick, s); ``speedup`` (``tick_s["1"] /
    tick_s["2"]``); ``by_replica`` (per number of processes and measured tick, the coaches each
    replica decided, from the setpoints); ``db_share`` (per number of processes: time in cursor
    executes / process time over the measured ticks, the mean over the processes);
    ``exactly_once`` (every coach had exactly one setpoint at every tick); ``runs`` (per number of
    processes: the warm-up ticks, the coaches that changed replica, the reasons of the last tick,
    the machine's CPU and every process's figures, see :func:`_run`); ``target`` and
    ``target_met``; the set-up's time; the model; the PostgreSQL server's version and settings;
    the machine with its 1-min load average before and after.
    """
    from trainclimate.bench.service import LEAD_IN_TICKS
    from trainclimate.bench.service.database import (
        PG_SERVER,
        BenchDatabase,
        ServiceBenchError,
        libpq_url,
        postgres,
        sql,
    )
    from trainclimate.bench.service.fleet import model_file
    from trainclimate.bench.service.tick import live_fleet
    from trainclimate.service.settings import Settings

    if coaches < 4 or coaches % 2:
        raise ReplicasBenchError("--coaches must be an even number ≥ 4 (pairs of coaches)")
    if batch < 1:
        raise ReplicasBenchError("the batch must be ≥ 1 coach")
    server = db or os.environ.get("TRAINCLIMATE_TEST_PG_URL") or PG_SERVER
    try:
        libpq_url(server)
    except ServiceBenchError:
        raise ReplicasBenchError(
            "--db takes a PostgreSQL server (a throw-away database is made on it), "
            f"not {server.split(':', 1)[0]}"
        ) from None
    step = progress or (lambda n: None)
    load_before = os.getloadavg()[0]
    rounds = WARM_UP_TICKS + MEASURED_TICKS
    with tempfile.TemporaryDirectory(prefix="tc-replicas-") as tmp, ExitStack() as stack:
        try:
            url = stack.enter_context(BenchDatabase(None, server))
        except ServiceBenchError as exc:
            raise ReplicasBenchError(str(exc)) from None
        t0 = time.perf_counter()
        model, model_kind = model_file(Path(tmp))
        period = timedelta(minutes=Settings(database_url=url, predictor_path=model).sampling_min)
        ids, start = live_fleet(url, model, coaches, LEAD_IN_TICKS + rounds, period)
        setup_s = time.perf_counter() - t0
        step(1)
        ticks = [start + (LEAD_IN_TICKS + k + 1) * period for k in range(rounds)]
        runs = {}
        for p in PROCESSES:
            # every run decides the same ticks on the same telemetry, from the same tables
            sql(
                url,
                "DELETE FROM setpoints",
                "DELETE FROM setpoint_rollups",
                "UPDATE coaches SET last_tick = NULL, held_by = NULL",
            )
            sql(url, "VACUUM ANALYZE coaches, setpoints, setpoint_rollups", autocommit=True)
            runs[str(p)] = _run(url, model, p, ticks, len(ids), batch, Path(tmp))
            step(1)
        server_info = postgres(url)
    tick_s = {p: r["tick_s"] for p, r in runs.items()}
    speedup = tick_s["1"] / tick_s["2"]
    exactly_once = all(r["exactly_once"] for r in runs.values())
    return {
        "coaches": len(ids),
        "activated": len(ids) // 2,
        "batch": batch,
        "tick_s": tick_s,
        "tick_s_runs": {p: r["tick_s_runs"] for p, r in runs.items()},
        "speedup": speedup,
        "by_replica": {p: r["by_replica"] for p, r in runs.items()},
        "db_share": {p: r["db_share"] for p, r in runs.items()},
        "exactly_once": exactly_once,
        "runs": runs,
        "target": {"tick_s_2_processes": TARGET_TICK_S, "speedup": TARGET_SPEEDUP},
        "target_met": tick_s["2"] <= TARGET_TICK_S and speedup >= TARGET_SPEEDUP and exactly_once,
        "setup_s": setup_s,
        "model": model_kind,
        "database": server_info,
        "machine": {
            **machine(),
            "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
        },
    }


def _run(
    url: str,
    model: Path,
    processes: int,
    ticks: list[datetime],
    coaches: int,
    batch: int,
    tmp: Path,
) -> dict:
    """``processes`` child processes issuing ``ticks`` together (the first
    :data:`WARM_UP_TICKS` unmeasured), each tick checked in the database: the measured ticks'
    times (s, and their median), the coaches each replica decided and those decided by another
    replica than at the previous tick (:func:`_check`), whether every coach had exactly one
    setpoint at every tick, the last tick's reasons, the machine's CPU over the
    measured ticks (:func:`_cpu`) and every process's figures (:func:`_summary`). The processes'
    stderr goes to files in ``tmp``."""
    names = [f"bench-replica-{i}" for i in range(1, processes + 1)]
    with ExitStack() as stack:
        children = []
        for name in names:
            log = tmp / f"{name}.log"
            proc = start_child(
                "run_replica",
                url,
                str(model),
                name,
                str(batch),
                stderr=stack.enter_context(log.open("w")),
            )
            stack.callback(_stop, proc)
            children.append((proc, log))
        for proc, log in children:
            if _line(proc, log) != "ready":
                raise RuntimeError(f"{log.stem} did not start")
        done = []
        for k, tick in enumerate(ticks):
            cpu0 = _machine_cpu_s()
            start = time.time() + START_DELAY_S
            for proc, _ in children:
                proc.stdin.write(f"{tick.isoformat()} {start!r}\n")
                proc.stdin.flush()
            ends = [json.loads(_line(proc, log))["end"] for proc, log in children]
            cpu1 = _machine_cpu_s()
            tick_s = max(ends) - start
            busy = None if cpu0 is None else cpu1 - cpu0
            previous = ticks[k - 1] if k else None
            done.append(
                {"tick_s": tick_s, "machine_cpu_s": busy, **_check(url, tick, previous, coaches)}
            )
        results = []
        for proc, log in children:
            proc.stdin.close()
            results.append(json.loads(_line(proc, log)))
            proc.wait()
    measured = done[WARM_UP_TICKS:]
    summaries = [_summary(r) for r in results]
    return {
        "tick_s": float(np.median([d["tick_s"] for d in measured])),
        "tick_s_runs": [d["tick_s"] for d in measured],
        "warm_up_s": [d["tick_s"] for d in done[:WARM_UP_TICKS]],
        "by_replica": [d["by_replica"] for d in measured],
        "changed_replica": [d["changed_replica"] for d in measured],
        "db_share": float(np.mean([s["db_share"] for s in summaries])),
        "exactly_once": all(d["exactly_once"] for d in done),
        "reasons": done[-1]["reasons"],
        "cpu": _cpu(measured, summaries),
        "processes": summaries,
    }


def _stop(proc) -> None:
    """Kill the child ``proc`` if it is still running (the benchmark failed)."""
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def _line(proc, log: Path) -> str:
    """The next line ``proc`` prints; a child that ended without it is an error (with the end of
    its stderr, ``log``)."""
    line = proc.stdout.readline()
    if not line:
        proc.wait()
        tail = log.read_text(errors="replace")[-2000:]
        raise RuntimeError(f"{log.stem} ended (exit code {proc.returncode}):\n{tail}")
    return line.strip()


def _check(url: str, tick: datetime, previous: datetime | None, coaches: int) -> dict:
    """The setpoints of ``tick`` in the database: how many, of how many coaches, whether each of
    the ``coaches`` has exactly one, how many each replica decided, their reasons and, after the
    ``previous`` tick of the same processes, ``changed_replica``: the coaches another replica
    decided than at ``previous``, and the mean step time (ms) of the DDPC decisions of those and
    of the others (a controller that did not see the previous tick rebuilds its state estimate
    over ρ samples; one new to its process is also built first, which the step time leaves out).
    """
    from trainclimate.bench.service.database import sql_all

    def one(statement: str) -> list:
        return sql_all(url, statement, (tick,))

    n, distinct = one("SELECT count(*), count(DISTINCT coach_id) FROM setpoints WHERE tick = %s")[0]
    by_replica = one(
        "SELECT replica, count(*) FROM setpoints WHERE tick = %s GROUP BY 1 ORDER BY 1"
    )
    reasons = one("SELECT reason, count(*) FROM setpoints WHERE tick = %s GROUP BY 1 ORDER BY 1")
    changed = None
    if previous is not None:
        rows = sql_all(
            url,
            "SELECT s.replica <> p.replica, count(*), avg(s.step_time_ms) FILTER "
            "(WHERE s.source = 'ddpc') FROM setpoints s JOIN setpoints p "
            "ON p.coach_id = s.coach_id AND p.tick = %s WHERE s.tick = %s GROUP BY 1",
            (previous, tick),
        )
        by = {moved: (count, step_ms) for moved, count, step_ms in rows}
        changed = {
            "coaches": by.get(True, (0, None))[0],
            "ddpc_step_ms": by.get(True, (0, None))[1],
            "others_ddpc_step_ms": by.get(False, (0, None))[1],
        }
    return {
        "setpoints": n,
        "exactly_once": n == distinct == coaches,
        "by_replica": dict(by_replica),
        "reasons": dict(reasons),
        "changed_replica": changed,
    }


def _machine_cpu_s() -> float | None:
    """CPU time the machine has spent busy since its start, over all cores (``/proc/stat``: all
    but idle and I/O wait), in s; None where there is no ``/proc/stat``."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return None
    return (sum(fields[:8]) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def _peak_rss_mb() -> float | None:
    """This process's peak resident memory in MB (MiB) since its program started (``VmHWM``;
    ``getrusage`` would count the parent it was forked from); None without ``/proc``."""
    try:
        with open("/proc/self/status") as f:
            return next(int(x.split()[1]) / 1024 for x in f if x.startswith("VmHWM:"))
    except OSError:
        return None


def _cpu(measured: list[dict], summaries: list[dict]) -> dict | None:
    """The machine's CPU over the measured ticks (medians): busy core-seconds, those of the
    replicas (their own CPU time) and the rest (the PostgreSQL server, and anything else running),
    and the share of all cores busy over the tick; None without ``/proc/stat``."""
    if measured[0]["machine_cpu_s"] is None:
        return None
    busy = np.array([d["machine_cpu_s"] for d in measured])
    replicas = np.array([sum(s["cpu_s"][k] for s in summaries) for k in range(len(measured))])
    tick_s = np.array([d["tick_s"] for d in measured])
    return {
        "busy_core_s": float(np.median(busy)),
        "replicas_core_s": float(np.median(replicas)),
        "rest_core_s": float(np.median(busy - replicas)),
        "busy_share": float(np.median(busy / ((os.cpu_count() or 1) * tick_s))),
    }


def _summary(result: dict) -> dict:
    """One process's figures over the measured ticks: the coaches it issued, its own time, its
    CPU time and its database time per tick (s), its database share (cursor executes / own time,
    over the measured ticks), the tick's parts (medians, s; ``other``: the own time less the
    telemetry reads, the samples and the decisions), the controllers it built per tick and in all
    (warm-up ticks included: the controllers it holds) and its peak memory in MB."""
    ticks = result["ticks"][WARM_UP_TICKS:]
    own = [t["own_s"] for t in ticks]
    database = [t["parts_s"].get("database", 0.0) for t in ticks]
    parts = {p: float(np.median([t["parts_s"].get(p, 0.0) for t in ticks])) for p in PARTS}
    other = [
        t["own_s"]
        - sum(t["parts_s"].get(p, 0.0) for p in ("telemetry_read", "samples", "decisions"))
        for t in ticks
    ]
    return {
        "replica": result["replica"],
        "issued": [t["issued"] for t in ticks],
        "own_s": own,
        "cpu_s": [t["cpu_s"] for t in ticks],
        "database_s": database,
        "db_share": sum(database) / sum(own),
        "parts_s": {**parts, "other": float(np.median(other))},
        "controllers_built": [t["calls"].get("controller_builds", 0) for t in ticks],
        "controllers": sum(t["calls"].get("controller_builds", 0) for t in result["ticks"]),
        "peak_rss_mb": result["peak_rss_mb"],
    }


# --- a replica: the child process ----------------------------------------------------------------
class _Parts:
    """Where a process's ticks spend their time, in s, summed until :meth:`take`: the functions
    wrapped with :meth:`timed` (and how often they were called), the cursor executes
    (``database``; those within a timed function also as ``database_in_{part}``) and the commits
    (``database_commit``)."""

    def __init__(self) -> None:
        self.s: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.within: str | None = None
        self.t0 = 0.0

    def add(self, part: str, seconds: float) -> None:
        self.s[part] = self.s.get(part, 0.0) + seconds

    def timed(self, part: str, fn):
        """``fn``, its time added to ``part`` and its calls counted."""

        def timed_fn(*args, **kwargs):
            outer, self.within, t0 = self.within, part, time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.add(part, time.perf_counter() - t0)
                self.calls[part] = self.calls.get(part, 0) + 1
                self.within = outer

        return timed_fn

    def started(self, *args) -> None:
        """A cursor execute or a commit starts (the engine's event)."""
        self.t0 = time.perf_counter()

    def executed(self, *args) -> None:
        """A cursor execute ended (``after_cursor_execute``)."""
        seconds = time.perf_counter() - self.t0
        self.add("database", seconds)
        if self.within is not None:
            self.add(f"database_in_{self.within}", seconds)

    def committed(self, *args) -> None:
        """A commit ended (the session's ``after_commit``)."""
        self.add("database_commit", time.perf_counter() - self.t0)

    def take(self) -> tuple[dict[str, float], dict[str, int]]:
        """The times and the calls counted so far (and start again from none)."""
        out = self.s, self.calls
        self.s, self.calls = {}, {}
        return out


def run_replica(url: str, model: str, name: str, batch: str) -> dict:
    """A service replica, as the child ``python -m trainclimate.bench run_replica URL MODEL NAME
    BATCH``: ``Scheduler(Database(URL), Settings(..., replica_name=NAME))``, its tick's parts
    timed (:class:`_Parts`). It prints ``ready``; then, for each line ``TICK START`` of its stdin
    (the tick in ISO 8601, the start in Unix time, s) it waits until START, issues TICK to the live
    fleet (``tick_fleet("live", TICK, BATCH)``) and prints the tick's record as a line of JSON:
    the coaches it issued, its start and end (Unix time, s), its own time and CPU time, the parts
    (s) and the calls of the timed functions. At the end of its stdin: every record, with its name
    and peak memory in MB (:func:`_peak_rss_mb`)."""
    from sqlalchemy import event

    from trainclimate.service import scheduler as scheduler_module
    from trainclimate.service.scheduler import Scheduler
    from trainclimate.service.settings import Settings
    from trainclimate.service.store.db import Database

    db = Database(url)
    settings = Settings(database_url=url, predictor_path=Path(model), replica_name=name)
    scheduler = Scheduler(db, settings)
    parts = _Parts()
    # the tick's parts, timed where the scheduler calls them (in this process only); the
    # controllers it builds (one per activated coach new to this process) within the decisions
    scheduler_module.DDPCController = parts.timed(
        "controller_builds", scheduler_module.DDPCController
    )
    scheduler_module.load_rows = parts.timed("telemetry_read", scheduler_module.load_rows)
    scheduler_module.controller_samples = parts.timed(
        "samples", scheduler_module.controller_samples
    )
    scheduler.decide = parts.timed("decisions", scheduler.decide)
    event.listen(db.engine, "before_cursor_execute", parts.started)
    event.listen(db.engine, "after_cursor_execute", parts.executed)
    event.listen(db.engine, "commit", parts.started)
    event.listen(db.sessions, "after_commit", parts.committed)
    print("ready", flush=True)
    records = []
    for line in iter(sys.stdin.readline, ""):
        tick, start = line.split()
        time.sleep(max(0.0, float(start) - time.time()))
        parts.take()
        cpu0, t0 = time.process_time(), time.time()
        issued = scheduler.tick_fleet("live", datetime.fromisoformat(tick), int(batch))
        t1 = time.time()
        parts_s, calls = parts.take()
        records.append(
            {
                "issued": issued,
                "start": t0,
                "end": t1,
                "own_s": t1 - t0,
                "cpu_s": time.process_time() - cpu0,
                "parts_s": parts_s,
                "calls": calls,
            }
        )
        print(json.dumps(records[-1]), flush=True)
    db.dispose()
    return {"replica": name, "ticks": records, "peak_rss_mb": _peak_rss_mb()}


def text(d: dict) -> str:
    """Three lines: the tick by 1 and by 2 processes, the speed-up and the target; how the 2
    processes split the coaches, how many changed replica, whether each had exactly one setpoint;
    the database's share of the processes' time and how busy the machine's cores were."""
    t, runs = d["tick_s"], d["runs"]
    split = " / ".join(
        f"{int(np.median([b.get(r, 0) for b in d['by_replica']['2']])):,}"
        for r in sorted({r for b in d["by_replica"]["2"] for r in b})
    )
    changed = int(np.median([c["coaches"] for c in runs["2"]["changed_replica"]]))
    busy = " / ".join(
        f"{runs[p]['cpu']['busy_share']:.0%}" if runs[p]["cpu"] else "n/a" for p in ("1", "2")
    )
    return (
        f"{d['coaches']:,} live coaches ({d['activated']:,} activated) on PostgreSQL "
        f"{d['database']['version'].split()[0]}, one tick: 1 process {t['1']:.2f} s, 2 processes "
        f"{t['2']:.2f} s (speed-up {d['speedup']:.2f}×; target ≤ {TARGET_TICK_S:g} s and ≥ "
        f"{TARGET_SPEEDUP:g}×: {'met' if d['target_met'] else 'missed'})\n"
        f"2 processes took {split} coaches per tick (median), {changed:,} of them from the other "
        f"one; every coach exactly one setpoint per tick: {'yes' if d['exactly_once'] else 'NO'}\n"
        f"time in the database (cursor executes): 1 process {d['db_share']['1']:.0%}, 2 processes "
        f"{d['db_share']['2']:.0%} of their time; the machine's cores busy {busy} during the tick"
    )
