"""The service benchmark's synthetic fleet: coach ids and their registration, plausible 1-minute
telemetry, users' tokens, the model file and the app in-process."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def pair_ids(prefix: str, trains: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Coach ids ``{prefix}{train:03d}-A`` (activated) and ``-B`` of ``trains`` trains (the
    train's number on as many digits as the largest needs, at least 3: every id of one length, as
    a COPY block takes them): (ids, train index, activated) per coach, A and B of each train next
    to each other."""
    width = max(3, len(str(trains - 1)))
    ids = [f"{prefix}{t:0{width}d}-{s}" for t in range(trains) for s in "AB"]
    train = np.repeat(np.arange(trains), 2)
    active = np.tile([True, False], trains)
    return ids, train, active


def register(url: str, ids: list[str], fleet: str) -> None:
    """Trains and coaches (``{train}-A`` activated), straight into the tables."""
    import psycopg

    trains = sorted({c.rsplit("-", 1)[0] for c in ids})
    with psycopg.connect(url) as conn, conn.cursor() as cur:
        cur.executemany(
            "INSERT INTO trains (id, name, created_at) VALUES (%s, %s, now())",
            [(t, t) for t in trains],
        )
        cur.executemany(
            "INSERT INTO coaches (id, train_id, fleet, ddpc_active, created_at) "
            "VALUES (%s, %s, %s, %s, now())",
            [(c, c.rsplit("-", 1)[0], fleet, c.endswith("-A")) for c in ids],
        )


def synthetic(rng, train: np.ndarray, active: np.ndarray, minute: np.ndarray) -> dict:
    """Plausible 1-minute telemetry of coaches in regular mode (numpy, no simulation): a daily
    cycle of T_amb around 4 °C and of the sun, rooms at 21–22 °C with sensor noise, T_rule 22 °C
    and an activated coach's T_ref below it, HVAC power 5–10 kW (≈ 10 % less when activated).
    ``minute`` counts minutes since midnight UTC of the first day; arrays of one length."""
    from trainclimate.service.store.telemetry import VALUE_COLS

    n = len(minute)
    hour = (minute % 1440) / 60.0
    t_amb = 4.0 + 4.0 * np.sin(2 * np.pi * (hour - 9.0) / 24.0) + 0.3 * (train % 7)
    t_amb += rng.normal(0.0, 0.3, n)
    sun = np.clip(np.sin(np.pi * (hour - 7.0) / 10.0), 0.0, None) * (hour > 7.0) * (hour < 17.0)
    ghi = 450.0 * sun * rng.uniform(0.5, 1.0, n)
    mid = 21.6 - 0.3 * active + rng.normal(0.0, 0.2, n)
    power = 7.5 + 1.0 * np.sin(2 * np.pi * (hour - 3.0) / 24.0) - 0.15 * (t_amb - 4.0)
    power = np.clip(power + rng.normal(0.0, 0.8, n), 5.0, 10.0) * np.where(active, 0.9, 1.0)
    values = {
        "t_room_up_c": mid + 0.3 + rng.normal(0.0, 0.1, n),
        "t_room_mid_c": mid,
        "t_room_low_c": mid - 0.3 + rng.normal(0.0, 0.1, n),
        "t_ref_c": 22.0 - 0.8 * active,
        "t_rule_c": np.full(n, 22.0),
        "t_amb_c": t_amb,
        "q_gt_w_m2": 0.45 * ghi,
        "q_gs_w_m2": 0.25 * ghi,
        "occupancy_pct": np.clip(rng.normal(25.0, 15.0, n), 0.0, 150.0),
        "speed_kmh": rng.uniform(0.0, 120.0, n),
        "ghi_w_m2": ghi,
        "power_kw": power,
        "floor_power_kw": 0.2 * power,  # the floor heating's share, as a winter coach's
    }
    return {c: np.broadcast_to(np.asarray(values[c], float), (n,)) for c in VALUE_COLS}


def tokens(url: str, *roles: str) -> list[dict]:
    """Authorization headers of new users with ``roles``."""
    from trainclimate.service.store.db import Database
    from trainclimate.service.store.tokens import create_token

    db = Database(url)
    headers = []
    with db.transaction() as session:
        for role in roles:
            token, _ = create_token(session, role, f"bench-{role}")
            headers.append({"Authorization": f"Bearer {token}"})
    db.dispose()
    return headers


def model_file(directory: Path) -> tuple[Path, str]:
    """The model file the app registers, and which it is: the cached default model if it exists
    (never built here), else a Transient Predictor at the same setting (5 min, ρ = 12, T = 6)
    fitted in about 2 s on white-noise inputs through first-order room dynamics and saved in
    ``directory``: valid, which is all the tick needs."""
    from types import SimpleNamespace

    from trainclimate.predict import TransientPredictor
    from trainclimate.predict.artifact import save_predictor
    from trainclimate.predict.default import default_model_path

    path = default_model_path()
    if path.exists():
        return path, "default (cached)"
    rng = np.random.default_rng(0)
    trajectories = []
    for _ in range(20):
        n = 200
        u = 22.0 + rng.uniform(-2.0, 2.0, n)
        d = np.column_stack(
            [
                rng.normal(5.0, 5.0, n),
                rng.uniform(0.0, 300.0, n),
                rng.uniform(0.0, 200.0, n),
                rng.uniform(0.0, 100.0, n),
                rng.uniform(0.0, 120.0, n),
            ]
        )
        y = np.empty((n, 3))
        y[0] = 21.5
        gain = d[:, 1] * 2e-3 + d[:, 2] * 1e-3 + d[:, 3] * 1e-2
        for k in range(n - 1):
            drive = 0.25 * (u[k] - y[k]) + 0.03 * (d[k, 0] - y[k]) + gain[k]
            y[k + 1] = y[k] + drive + np.array([0.05, 0.0, -0.05]) + rng.normal(0.0, 0.05, 3)
        trajectories.append(SimpleNamespace(y=y, u=u[:, None], d=d, sampling_min=5))
    predictor = TransientPredictor(12, 6).fit(trajectories)
    return save_predictor(predictor, directory / "bench-model.npz"), "small (fitted here)"


def app(url: str, model: Path):
    """The service in-process (migrations, model registration); its live loop only runs once at
    start (its interval is 3600 s), so nothing else writes while a benchmark runs."""
    from trainclimate.service.app import create_app
    from trainclimate.service.settings import Settings

    settings = Settings(database_url=url, predictor_path=model, scheduler_interval_s=3600.0)
    return create_app(settings)


def client(url: str, model: Path):
    """:func:`app` behind starlette's TestClient (in this process, its lifespan run). Starlette
    warns, when its test client is imported, that driving it with httpx (the HTTP client the
    product pins) is deprecated; that says nothing about the figures, so it is not printed."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Using `httpx` with `starlette.testclient`")
        from fastapi.testclient import TestClient
    return TestClient(app(url, model))
