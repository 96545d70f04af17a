"""Benchmarks (``trainclimate bench …``): speed figures measured against a baseline in one run.

Every benchmark module has ``run(...) -> dict`` (the figures, the JSON of ``bench … --json``) and
``text(d) -> str`` (their human-readable summary); importing this package imports none of them.

- :mod:`.common` — what several benchmarks share: :func:`~.common.machine`, peak resident
  memory, percentiles in ms, the child-process runner
- :mod:`.__main__` — the child processes' entry (``python -m trainclimate.bench NAME …``): a
  pipeline run, the parse-only baseline, a predictor fit, each reporting its own time and memory
- :mod:`.simulator` — the vectorised fleet simulator against a per-coach loop (coach-days/s)
- :mod:`.pipeline` — the data pipeline against plain CSV parsing (raw rows/s, peak MB)
- :mod:`.calibration` — a twin's calibration per coach-week, and its Jacobian's parameter sets
  as one fleet against one simulation each (s)
- :mod:`.predictor` — the streaming Transient Predictor fit against one QR (s, peak MB)
- :mod:`.controller` — the OCP solve three ways, the controller step, a fleet tick (ms, s)
- :mod:`.service` — the service on PostgreSQL: ingest (rows/s), the pair comparison's latency
  (ms), the live fleet's tick (s)
- :mod:`.load` — ``serve --fleet demo`` as its own process under many concurrent clients
  (statuses, latency in ms, requests/s, the loop's ticks) against one client in sequence
- :mod:`.dashboard` — the operator dashboard of a running service in Chromium: first-load bytes
  transferred, idle requests a minute
"""
