"""SQL expressions of time that compile on PostgreSQL and SQLite alike."""

from __future__ import annotations

from sqlalchemy import Integer
from sqlalchemy.ext.compiler import compiles
from sqlalchemy.sql.expression import FunctionElement


class EpochSeconds(FunctionElement):
    """A timestamp column as whole seconds since 1970-01-01 UTC (an integer, so that dividing it
    by an integer floors on either database)."""

    type = Integer()
    inherit_cache = True


@compiles(EpochSeconds)  # PostgreSQL, and any other SQL standard database
def _epoch_pg(element, compiler, **kw):
    # date_part gives a double precision (EXTRACT a numeric: slower to compute)
    return f"CAST(FLOOR(date_part('epoch', {compiler.process(element.clauses, **kw)})) AS BIGINT)"


@compiles(EpochSeconds, "sqlite")
def _epoch_sqlite(element, compiler, **kw):
    return f"CAST(strftime('%s', {compiler.process(element.clauses, **kw)}) AS INTEGER)"


class OnMinute(FunctionElement):
    """Whether a timestamp column falls on a whole minute (the comparison's 1-minute grid)."""

    inherit_cache = True


@compiles(OnMinute)  # PostgreSQL, and any other SQL standard database
def _on_minute_pg(element, compiler, **kw):
    col = compiler.process(element.clauses, **kw)
    return f"(date_trunc('minute', {col}) = {col})"


@compiles(OnMinute, "sqlite")
def _on_minute_sqlite(element, compiler, **kw):
    return f"(strftime('%f', {compiler.process(element.clauses, **kw)}) = '00.000')"
