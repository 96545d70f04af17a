"""The service benchmark's PostgreSQL side: the throw-away database, plain SQL, and telemetry
loaded with binary COPY."""

from __future__ import annotations

import os
import time

import numpy as np

#: The server ``bench service`` creates its database on, unless ``$TRAINCLIMATE_TEST_PG_URL``
#: names another or ``--db`` gives a database.
PG_SERVER = "postgresql://postgres@127.0.0.1:5432/test"
_PG_EPOCH_S = 946_684_800  # 2000-01-01T00:00Z: PostgreSQL's binary timestamps count from here
_COPY_SIGNATURE = b"PGCOPY\n\xff\r\n\x00" + bytes(8)  # binary COPY header (no flags, no extension)
#: Empties every table the benchmark writes.
RESET = (
    "TRUNCATE telemetry, window_rollups, coach_feed, setpoints, setpoint_rollups, pair_days, "
    "fleet_days, "
    "overrides, "
    "coach_liveness, coaches, trains, fleet_clocks, "
    "audit_log "
    "RESTART IDENTITY CASCADE"
)


class ServiceBenchError(Exception):
    """No usable database for ``bench service`` (the CLI's exit code 2)."""


def libpq_url(url: str) -> str:
    """``url`` for psycopg itself; a non-PostgreSQL URL is an error."""
    from trainclimate.service.store.db import normalise_url

    url = normalise_url(url)
    if not url.startswith("postgresql+psycopg://"):
        scheme = url.split(":", 1)[0]
        raise ServiceBenchError(f"the service benchmark needs PostgreSQL, not {scheme}")
    return "postgresql://" + url.split("://", 1)[1]


class BenchDatabase:
    """A fresh database on the server ``server`` (default ``$TRAINCLIMATE_TEST_PG_URL``, else
    :data:`PG_SERVER`; created here, dropped at the end), or the database ``url`` names, which
    must be empty (the benchmark fills and truncates its tables). As a context manager: the
    migrated database's libpq URL."""

    def __init__(self, url: str | None, server: str | None = None):
        import uuid

        self.given = url is not None
        if self.given:
            self.url = libpq_url(url)
            self.name = None
        else:
            server = libpq_url(server or os.environ.get("TRAINCLIMATE_TEST_PG_URL") or PG_SERVER)
            self.server = server
            self.name = f"tc_bench_{uuid.uuid4().hex[:10]}"
            self.url = f"{server.rsplit('/', 1)[0]}/{self.name}"

    def __enter__(self) -> str:
        """Create (or check) and migrate the database; its libpq URL. :class:`ServiceBenchError`
        if the server does not answer or the given database is not empty."""
        import psycopg

        from trainclimate.service.store.db import migrate

        try:
            if self.given:
                psycopg.connect(self.url).close()
            else:
                with psycopg.connect(self.server, autocommit=True) as conn:
                    conn.execute(f'CREATE DATABASE "{self.name}"')
        except psycopg.OperationalError as exc:
            first = (str(exc).strip() or type(exc).__name__).splitlines()[0]
            raise ServiceBenchError(f"no PostgreSQL database to benchmark on: {first}") from None
        try:
            migrate(self.url)
            with psycopg.connect(self.url) as conn:
                used = conn.execute(
                    "SELECT (SELECT count(*) FROM coaches) + (SELECT count(*) FROM telemetry)"
                ).fetchone()[0]
            if used:
                raise ServiceBenchError(
                    "--db: the database must be empty (the benchmark fills and truncates it)"
                )
        except BaseException:
            self.__exit__()
            raise
        return self.url

    def __exit__(self, *exc) -> None:
        """Drop the database if it was created here."""
        import psycopg

        if not self.given:
            with psycopg.connect(self.server, autocommit=True) as conn:
                conn.execute(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)')


def sql(url: str, *statements: str, autocommit: bool = False) -> list:
    """Run ``statements``; the first row of each (None if it returns none)."""
    import psycopg

    out = []
    with psycopg.connect(url, autocommit=autocommit) as conn:
        for s in statements:
            cur = conn.execute(s)
            out.append(cur.fetchone() if cur.description else None)
    return out


def sql_all(url: str, statement: str, params: tuple = ()) -> list:
    """Every row of ``statement`` with ``params``."""
    import psycopg

    with psycopg.connect(url) as conn:
        return conn.execute(statement, params).fetchall()


def in_schema(url: str, schema: str) -> str:
    """``url`` with ``schema`` first on the search path (a second set of tables)."""
    return f"{url}{'&' if '?' in url else '?'}options=-csearch_path%3D{schema}"


def postgres(url: str) -> dict:
    """The server's version and the settings that matter for these figures."""
    names = ("shared_buffers", "synchronous_commit", "fsync", "max_wal_size", "work_mem")
    rows = sql(url, "SHOW server_version", *(f"SHOW {n}" for n in names))
    return {"version": rows[0][0], **{n: r[0] for n, r in zip(names, rows[1:], strict=True)}}


def table_size(url: str) -> dict:
    """The telemetry table's size in MB (MiB), its partitions' summed: in all, its heap and its
    indexes."""
    total, heap, index = sql(
        url,
        "SELECT sum(pg_total_relation_size(relid)), sum(pg_relation_size(relid)), "
        "sum(pg_indexes_size(relid)) FROM pg_partition_tree('telemetry')",
    )[0]
    return {
        "total_mb": float(total) / 2**20,
        "heap_mb": float(heap) / 2**20,
        "indexes_mb": float(index) / 2**20,
    }


def copy_block(coach_ids: np.ndarray, time_s: np.ndarray, values: dict) -> bytes:
    """Telemetry rows in PostgreSQL's binary COPY format, built with numpy: coach_id, time (s
    since the epoch), the values, mode (``regular``) and connected (true); every row the same
    size (coach ids of one length), so one structured array holds them."""
    from trainclimate.service.store.telemetry import VALUE_COLS

    ids = np.asarray(coach_ids, dtype="S")
    width = ids.dtype.itemsize
    if np.char.str_len(ids).min() != width:  # numpy would pad the shorter ones with NUL bytes
        raise ValueError("coach ids of one COPY block must have the same length")
    fields = [("n", ">i2"), ("id_len", ">i4"), ("coach_id", f"S{width}")]
    fields += [("time_len", ">i4"), ("time", ">i8")]
    for c in VALUE_COLS:
        fields += [(f"{c}_len", ">i4"), (c, ">f8")]
    fields += [("mode_len", ">i4"), ("mode", "S7"), ("connected_len", ">i4"), ("connected", "u1")]
    a = np.empty(len(time_s), np.dtype(fields))
    a["n"] = 3 + len(VALUE_COLS) + 1
    a["id_len"], a["coach_id"] = width, ids
    a["time_len"] = 8
    a["time"] = np.round((np.asarray(time_s, float) - _PG_EPOCH_S) * 1e6).astype(np.int64)
    for c in VALUE_COLS:
        a[f"{c}_len"], a[c] = 8, values[c]
    a["mode_len"], a["mode"] = 7, b"regular"
    a["connected_len"], a["connected"] = 1, 1
    return a.tobytes()


def copy_telemetry(url: str, blocks) -> tuple[int, float]:
    """COPY the binary ``blocks`` (from :func:`copy_block`) into telemetry in one transaction:
    (bytes sent, s including the commit)."""
    import psycopg

    from trainclimate.service.store.telemetry import VALUE_COLS

    cols = ", ".join(("coach_id", "time", *VALUE_COLS, "mode", "connected"))
    sent, t0 = 0, time.perf_counter()
    statement = f"COPY telemetry ({cols}) FROM STDIN (FORMAT BINARY)"
    with psycopg.connect(url) as conn, conn.cursor() as cur, cur.copy(statement) as copy:
        copy.write(_COPY_SIGNATURE)
        for block in blocks:
            copy.write(block)
            sent += len(block)
        copy.write(b"\xff\xff")
    return sent, time.perf_counter() - t0
