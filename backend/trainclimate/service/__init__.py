"""The product: a FastAPI service that runs the DDPC layer for a fleet of coaches.

- :mod:`.app` — the application (:func:`~.app.create_app`) and its lifespan: migrations, the first
  model, the loops started and stopped with the server;
- :mod:`.settings` — the settings (``TRAINCLIMATE_*`` and the ``trainclimate serve`` options);
- :mod:`.preparation` — the first predictor model, prepared in the background;
- :mod:`.policy` — the pure decision policy: one coach's setpoint at one tick from plain inputs
  (override, stale, inactive, not in regular mode, no model, else the DDPC step);
- :mod:`.scheduler` — the ticks: claiming each (coach, tick) once in the database, in batches,
  the live fleet's loop, the active model and each coach's controller; it stores what the policy
  decides;
- :mod:`.store` — storage: the database and migrations, the ORM models, telemetry, what the API
  reads (queries) and writes (commands, audited), tokens and roles;
- :mod:`.api` — the HTTP API (``/api/v1``): one router per resource, the request and response
  schemas, the bearer token's check, the generated reference ``docs/api.md``;
- :mod:`.adapters` — the demo fleet (simulated in process) and the gateway emulator (a separate
  process speaking the live feed's HTTP protocol).

Dependencies point one way: ``api`` → ``store``; ``scheduler`` → ``policy``, ``store``;
``adapters`` → ``store``, ``scheduler``; ``app`` assembles them all. ``store`` imports nothing
from ``api``, ``scheduler`` or ``adapters``, and ``policy`` touches no database.
"""
