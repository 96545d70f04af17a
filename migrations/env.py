"""Alembic environment: the schema of trainclimate's service (see
backend/trainclimate/service/store).

The URL comes from the config built by :func:`trainclimate.service.store.db.alembic_config` (the
service applies the migrations at start) or, from the command line, from
``TRAINCLIMATE_DATABASE_URL``.
"""

from __future__ import annotations

import os

from alembic import context
from sqlalchemy import engine_from_config, pool

from trainclimate.service.store.db import normalise_url
from trainclimate.service.store.models import Base
from trainclimate.service.store.partitions import include_name

config = context.config
if not config.get_main_option("sqlalchemy.url"):
    config.set_main_option(
        "sqlalchemy.url", normalise_url(os.environ["TRAINCLIMATE_DATABASE_URL"]).replace("%", "%%")
    )
target_metadata = Base.metadata


def run_migrations_offline() -> None:
    context.configure(
        url=config.get_main_option("sqlalchemy.url"),
        target_metadata=target_metadata,
        literal_binds=True,
        render_as_batch=True,
        include_name=include_name,
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connectable = engine_from_config(
        config.get_section(config.config_ini_section, {}),
        prefix="sqlalchemy.",
        poolclass=pool.NullPool,
    )
    with connectable.connect() as connection:
        context.configure(
            connection=connection,
            target_metadata=target_metadata,
            render_as_batch=connection.dialect.name == "sqlite",
            include_name=include_name,  # telemetry's partitions are that one table's pieces
        )
        with context.begin_transaction():
            context.run_migrations()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
