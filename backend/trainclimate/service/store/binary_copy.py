"""Many rows read from PostgreSQL straight into numpy: a ``COPY (SELECT …) TO STDOUT (FORMAT
BINARY)`` whose columns are all 8-byte integers or floats, never NULL, parsed with one structured
dtype — no Python object per row or value. The fleet summary reads its window rollups this way
(hundreds of thousands of rows) and the scheduler its coaches' telemetry at every tick.

The format: an 11-byte signature, 4 bytes of flags, a 4-byte header-extension length and the
extension; then per row a 2-byte field count and per field a 4-byte length and the value
(big-endian); a 2-byte −1 at the end (PostgreSQL documentation, "COPY", *Binary Format*).
"""

from __future__ import annotations

import numpy as np
from psycopg import sql
from psycopg.rows import namedtuple_row
from sqlalchemy import Float, Select, Table, case, select
from sqlalchemy.orm import Session


class CopyShapeError(ValueError):
    """A binary COPY's rows are not the 8-byte, non-NULL columns they were read as."""


def parse(data: bytes, dtype: np.dtype) -> np.ndarray:
    """The rows of binary COPY output ``data`` as ``dtype`` (its fields in the columns' order,
    each ``int64`` or ``float64``); :class:`CopyShapeError` if a row is not of that shape
    (a NULL, another width)."""
    header = 11 + 4 + 4 + int.from_bytes(data[15:19], "big")
    body = data[header:-2]
    names = dtype.names or ()
    fields: list[tuple[str, str]] = [("n", ">i2")]
    for name in names:
        kind = ">i8" if dtype[name].kind == "i" else ">f8"
        fields += [(f"{name}_len", ">i4"), (name, kind)]
    wire = np.dtype(fields)
    if len(body) % wire.itemsize:
        raise CopyShapeError("the COPY's rows are not of the expected shape")
    rows = np.frombuffer(body, wire)
    if np.any(rows["n"] != len(names)) or any(np.any(rows[f"{n}_len"] != 8) for n in names):
        raise CopyShapeError("the COPY's rows are not of the expected shape")
    out = np.empty(len(rows), dtype)
    for name in names:
        out[name] = rows[name]
    return out


def copy_rows(session: Session, query: sql.Composable, dtype: np.dtype) -> np.ndarray:
    """The rows of ``query`` (a SELECT whose columns are ``dtype``'s fields, 8 bytes each,
    never NULL) read in the session's transaction with a binary COPY (PostgreSQL only)."""
    statement = sql.SQL("COPY ({}) TO STDOUT (FORMAT BINARY)").format(query)
    raw = session.connection().connection.driver_connection
    if raw is None:
        raise CopyShapeError("no driver connection to COPY through")
    with raw.cursor() as cursor, cursor.copy(statement) as copy:
        data = b"".join(bytes(block) for block in copy)
    return parse(data, dtype)


def coach_windows(
    session: Session, table: Table, columns: list[str], coaches: list[str], lo_w: int, hi_w: int
) -> np.ndarray:
    """The rows of a per-coach, per-window table (``coach_id``, ``window``: the window rollups)
    for ``coaches`` and windows lo_w ≤ w < hi_w, as one structured array — fields ``coach``
    (the position in ``coaches``), ``window`` and ``columns`` (float64 for a float column,
    int64 for the others) — in no particular order: on PostgreSQL one binary COPY, elsewhere
    the driver's tuples."""
    dtype = np.dtype(
        [("coach", np.int64), ("window", np.int64)]
        + [(c, np.float64 if isinstance(table.c[c].type, Float) else np.int64) for c in columns]
    )
    if not coaches:
        return np.zeros(0, dtype)
    if session.get_bind().dialect.name != "postgresql":
        position = case({c: i for i, c in enumerate(coaches)}, value=table.c.coach_id)
        rows = session.execute(
            select(position, table.c.window, *(table.c[c] for c in columns)).where(
                table.c.coach_id.in_(coaches), table.c.window >= lo_w, table.c.window < hi_w
            )
        ).all()
        return np.array([tuple(row) for row in rows], dtype)
    query = sql.SQL(
        'SELECT k.i - 1, r."window", {columns} FROM {table} r '
        "JOIN unnest({ids}::text[]) WITH ORDINALITY AS k(id, i) ON r.coach_id = k.id "
        'WHERE r."window" >= {lo} AND r."window" < {hi}'
    ).format(
        columns=sql.SQL(", ").join(
            sql.SQL("r.{}::{}").format(
                sql.Identifier(c), sql.SQL("float8" if dtype[c].kind == "f" else "int8")
            )
            for c in columns
        ),
        table=sql.Identifier(table.name),
        ids=sql.Literal(list(coaches)),
        lo=sql.Literal(int(lo_w)),
        hi=sql.Literal(int(hi_w)),
    )
    return copy_rows(session, query, dtype)


def rows(session: Session, statement: Select) -> list:
    """The rows of ``statement`` as named tuples: on PostgreSQL in the binary format, which
    sends a ``bytea`` as it is (the text format doubles it in hex, and costs twice as long to
    read, measured), elsewhere the driver's rows."""
    if session.get_bind().dialect.name != "postgresql":
        return list(session.execute(statement))
    compiled = statement.compile(
        dialect=session.get_bind().dialect, compile_kwargs={"render_postcompile": True}
    )
    raw = session.connection().connection.driver_connection
    if raw is None:
        raise CopyShapeError("no driver connection to read through")
    with raw.cursor(binary=True, row_factory=namedtuple_row) as cursor:
        return cursor.execute(str(compiled), compiled.params).fetchall()
