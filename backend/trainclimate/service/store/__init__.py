"""Storage: everything the service keeps in SQL, and the reads and writes on it.

- :mod:`.db` — engines and sessions (SQLite or PostgreSQL), the schema through the Alembic
  migrations in ``migrations/``;
- :mod:`.models` — the ORM models (trains, coaches, fleet clocks, telemetry, setpoints, overrides,
  predictor models, users, tokens, the audit log);
- :mod:`.telemetry` — storing 1-minute telemetry rows and turning them into the controller's
  samples; the rows' wire format and the rows of a simulation;
- :mod:`.queries` — what the API reads (coach views, time series, setpoints, pair comparisons);
- :mod:`.records` — the typed dicts that cross the store's seams: a telemetry row as stored, the
  views the API reads;
- :mod:`.comfort` — whether a coach's decks are within the comfort band now (its newest row);
- :mod:`.fleet_summary` — the fleet at a glance: every train's savings and comfort summed in the
  database, pooled, and the coaches that need attention;
- :mod:`.attention` — the coaches that need attention and the coaches by status, from their views;
- :mod:`.model_health` — the stored predictions against the temperatures measured afterwards;
- :mod:`.commands` — what the API writes, each write audited;
- :mod:`.tokens` — bearer tokens (only their SHA-256 is stored), roles and who a token belongs to.

It imports nothing from the API, the scheduler or the adapters: they build on it.
"""
