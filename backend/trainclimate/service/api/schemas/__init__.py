"""Request and response bodies of the HTTP API (pydantic), with the examples OpenAPI shows.

- :mod:`.base` — the strict request body, digits-only integers, coach ids, the error message;
- :mod:`.health` — the service's health, readiness and replicas;
- :mod:`.telemetry` — the live feed: telemetry rows and batches, the setpoint a gateway pulls;
- :mod:`.coaches` — a coach's view, registration, time series, setpoints and overrides;
- :mod:`.trains` — a train, its trial plan and its guard;
- :mod:`.savings` — a train's pair comparison and the fleet summary;
- :mod:`.models` — the predictor models, retraining and a model's health;
- :mod:`.users` — users, tokens, roles and the audit log.
"""
