"""Many rows read from PostgreSQL straight into numpy: columns that are all 8-byte integers or
floats, never NULL, packed by the server into one ``bytea`` (each row's values in their binary
send format, big-endian, rows one after the other: ``int8send``/``float8send`` and
``string_agg``) and read with one structured dtype — one value for the client to receive instead
of a message per row (a binary COPY's), and no Python object per row or value. The fleet summary
reads its window rollups this way (tens of thousands of rows) and the scheduler its coaches'
telemetry at every tick. A value is at most 1 GB in PostgreSQL: one read holds up to about 10 M
rows of 12 columns, far more than either reads (a 31-day summary of 900 coaches without pair
days: 1.3 M window rollups).
"""

from __future__ import annotations

import numpy as np
from psycopg import sql
from sqlalchemy import Float, Table, case, select
from sqlalchemy.orm import Session


class RowShapeError(ValueError):
    """Packed rows are not the 8-byte, non-NULL columns they were read as."""


def packed_rows(session: Session, query: sql.Composable, dtype: np.dtype) -> np.ndarray:
    """The rows of ``query`` (a SELECT whose columns are ``dtype``'s fields in order, each
    ``int64`` or ``float64``, or a ``bytea`` of float64 values in the machine's order (numpy's
    ``tobytes``) read as a fixed-size float64 field, never NULL) read in the session's
    transaction as one packed ``bytea`` (PostgreSQL only), in no particular order.
    :class:`RowShapeError` if a value was NULL or a ``bytea`` was not its field's size (the
    packed rows then do not add up to the server's count of rows)."""
    names = dtype.names or ()

    def sent(name: str) -> sql.Composable:
        column = sql.SQL("q.{}").format(sql.Identifier(name))
        if dtype[name].subdtype is not None:
            return column  # its bytes as they are
        send = "int8send" if dtype[name].kind == "i" else "float8send"
        return sql.SQL("{}({})").format(sql.SQL(send), column)

    packed = sql.SQL(" || ").join(sent(name) for name in names)
    # a row counts only if each bytea is its field's size: one that is not then leaves the
    # packed rows longer than the count says
    sized = [
        sql.SQL("length(q.{}) = {}").format(sql.Identifier(name), sql.Literal(dtype[name].itemsize))
        for name in names
        if dtype[name].subdtype is not None
    ]
    statement = sql.SQL(
        "SELECT count(*) FILTER (WHERE {sized}), "
        "coalesce(string_agg({packed}, ''::bytea), ''::bytea) FROM ({query}) AS q({names})"
    ).format(
        sized=sql.SQL(" AND ").join(sized) if sized else sql.SQL("true"),
        packed=packed,
        query=query,
        names=sql.SQL(", ").join(sql.Identifier(n) for n in names),
    )
    raw = session.connection().connection.driver_connection
    if raw is None:
        raise RowShapeError("no driver connection to read through")
    with raw.cursor(binary=True) as cursor:
        n, data = cursor.execute(statement).fetchone()
    wire = np.dtype(
        [
            (name, dtype[name])
            if dtype[name].subdtype is not None
            else (name, ">i8" if dtype[name].kind == "i" else ">f8")
            for name in names
        ]
    )
    if len(data) != n * wire.itemsize:
        raise RowShapeError("a packed row is missing or misshapen: a value was NULL or resized")
    return np.frombuffer(data, wire).astype(dtype)


def coach_windows(
    session: Session, table: Table, columns: list[str], coaches: list[str], lo_w: int, hi_w: int
) -> np.ndarray:
    """The rows of a per-coach, per-window table (``coach_id``, ``window``: the window rollups)
    for ``coaches`` and windows lo_w ≤ w < hi_w, as one structured array — fields ``coach``
    (the position in ``coaches``), ``window`` and ``columns`` (float64 for a float column,
    int64 for the others) — in no particular order: on PostgreSQL packed
    (:func:`packed_rows`), elsewhere the driver's tuples."""
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
    # each coach's windows read through the (coach, window) key: the subquery is kept apart
    # (OFFSET 0), so the planner cannot join the coaches to a scan of the whole table, whose
    # cost grows with the history kept (it did so for the setpoint rollups: 120 ms a chunk of
    # 256 coaches and a day at 40 days of history, against 83 ms through the key, measured)
    query = sql.SQL(
        'SELECT k.i - 1, r."window", {columns} '
        "FROM unnest({ids}) WITH ORDINALITY AS k(id, i) "
        'CROSS JOIN LATERAL (SELECT * FROM {table} WHERE coach_id = k.id AND "window" >= {lo} '
        'AND "window" < {hi} OFFSET 0) AS r'
    ).format(
        columns=sql.SQL(", ").join(
            sql.SQL("r.{}::{}").format(
                sql.Identifier(c), sql.SQL("float8" if dtype[c].kind == "f" else "int8")
            )
            for c in columns
        ),
        table=sql.Identifier(table.name),
        ids=array_of(coaches, "text"),
        lo=sql.Literal(int(lo_w)),
        hi=sql.Literal(int(hi_w)),
    )
    return packed_rows(session, query, dtype)


def array_of(values, element: str) -> sql.Composable:
    """``values`` as a PostgreSQL array of ``element`` (``text``, ``int4``, ``int8``): one
    literal of the values joined by spaces, split by the server. psycopg quotes a list element by
    element (256 coaches and 256 days: 0.4 ms a statement against 0.01 ms so, measured), and a
    summary sends thousands. Coach ids hold no space (letters, digits, ``_``, ``.``, ``-``);
    ValueError if a value does."""
    text = [str(v) for v in values]
    if any(" " in v or not v for v in text):
        raise ValueError("an array element is empty or holds a space")
    return sql.SQL("string_to_array({}, ' ')::{}[]").format(
        sql.Literal(" ".join(text)), sql.SQL(element)
    )


def rows(session: Session, query: sql.Composable) -> list[tuple]:
    """The rows of ``query`` (PostgreSQL only) in the binary format, which sends a ``bytea`` as
    it is (the text format doubles it in hex, and costs twice as long to read, measured)."""
    raw = session.connection().connection.driver_connection
    if raw is None:
        raise RowShapeError("no driver connection to read through")
    with raw.cursor(binary=True) as cursor:
        return cursor.execute(query).fetchall()
