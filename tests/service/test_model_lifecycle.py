"""The model lifecycle: retraining on the service's own telemetry, candidates in the shadow,
promotion by an admin, drift.

One simulated demo day (288 periods, ≈ 30 s on SQLite, the tests' small predictor active) is
stored once; each test works on a copy of that database file.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from datetime import timedelta

import numpy as np
import pandas as pd
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError

from helpers.cli import call
from helpers.service import API
from trainclimate.data.trajectory import Trajectory
from trainclimate.predict import TransientPredictor
from trainclimate.predict.artifact import load_predictor_bytes, predictor_bytes
from trainclimate.predict.evaluate import mae_per_step
from trainclimate.service.adapters import demo
from trainclimate.service.app import create_app
from trainclimate.service.preparation import register_predictor
from trainclimate.service.retrain import RetrainError, retrain
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.settings import Settings
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.model_health import drift
from trainclimate.service.store.models import (
    AuditLog,
    PredictorModel,
    Setpoint,
    ShadowPrediction,
    Telemetry,
)
from trainclimate.service.store.tokens import create_token

PERIODS = 288  # one simulated day
COLUMNS = ("time", "t_room_up_c", "t_room_mid_c", "t_room_low_c", "t_ref_c", "t_amb_c",
           "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh", "mode", "connected")  # fmt: skip


@pytest.fixture(scope="module")
def demo_day(tmp_path_factory, small_predictor):
    """A SQLite file: the demo fleet after one simulated day, the small predictor active."""
    path = tmp_path_factory.mktemp("demo") / "day.db"
    url = f"sqlite:///{path}"
    migrate(url)
    db = Database(url)
    with db.transaction() as s:
        register_predictor(s, small_predictor, "the tests' small predictor")
        demo.register(s)
    fleet = demo.DemoFleet(db, Scheduler(db, Settings(database_url=url)), speedup=1.0)
    for _ in range(PERIODS):
        fleet.advance()
    db.dispose()
    return path


@pytest.fixture
def demo_day_database(demo_day, tmp_path):
    path = tmp_path / "copy.db"
    shutil.copy(demo_day, path)
    database = Database(f"sqlite:///{path}")
    yield database
    database.dispose()


def by_hand(db: Database, coach_id: str) -> list[Trajectory]:
    """A coach's 5-min trajectories cut here without the pipeline: at ticks t on the 5-min
    clock, y(t) the row stamped t, u(t) and d(t) the means of the rows stamped t + 1 … t + 5 min;
    a sample counts when those six rows exist, regular, connected and not overridden; a run of
    at least 30 min (the pipeline's shortest piece: 6 samples) is a trajectory."""
    with db.transaction() as s:
        rows = s.execute(select(Telemetry).where(Telemetry.coach_id == coach_id)).scalars().all()
        frame = pd.DataFrame([{c: getattr(r, c) for c in COLUMNS} for r in rows]).set_index("time")
        overridden = set(
            s.scalars(
                select(Setpoint.tick).where(
                    Setpoint.coach_id == coach_id, Setpoint.source == "override"
                )
            )
        )
    frame.index = pd.DatetimeIndex(frame.index).tz_convert("UTC")
    ok = (frame["mode"] == "regular") & frame["connected"].astype(bool)
    ticks = frame.index[frame.index.minute % 5 == 0]
    samples = []
    for t in ticks:
        after = frame.reindex(pd.date_range(t + pd.Timedelta(minutes=1), periods=5, freq="1min"))
        good = (
            t in frame.index
            and after.notna().all().all()
            and ok.reindex(after.index).fillna(False).all()
            and t not in overridden
        )
        if good:
            y = frame.loc[t, ["t_room_up_c", "t_room_mid_c", "t_room_low_c"]].to_numpy(float)
            u = after[["t_ref_c"]].to_numpy(float).mean(axis=0)
            d = after[["t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh"]]
            samples.append((t, y, u, d.to_numpy(float).mean(axis=0)))
        else:
            samples.append(None)
    out, run = [], []
    for s_ in [*samples, None]:
        if s_ is not None and (not run or s_[0] - run[-1][0] == pd.Timedelta(minutes=5)):
            run.append(s_)
            continue
        if len(run) >= 6:
            out.append(
                Trajectory(
                    time=pd.DatetimeIndex([r[0] for r in run]),
                    y=np.array([r[1] for r in run]),
                    u=np.array([r[2] for r in run]),
                    d=np.array([r[3] for r in run]),
                    sampling_min=5,
                    coach=coach_id,
                )
            )
        run = [s_] if s_ is not None else []
    return out


def test_retraining_recovers_the_model_fitted_offline_on_the_same_trajectories(demo_day_database):
    result = retrain(demo_day_database, force=True)
    assert (result.version, result.state) == (2, "candidate")
    held = result.validation_coaches
    assert held == sorted(demo.coach_ids())[-5:]  # the last quarter of the 20 coaches
    training = [c for c in sorted(demo.coach_ids()) if c not in held]
    mine = [t for c in training for t in by_hand(demo_day_database, c)]
    offline = TransientPredictor(12, 6).fit(mine)
    validation = [t for c in held for t in by_hand(demo_day_database, c)]
    with demo_day_database.transaction() as s:
        model = s.scalar(select(PredictorModel).where(PredictorModel.version == 2))
        info, artifact = model.info, model.artifact
    registered = load_predictor_bytes(artifact)
    assert info["training"]["trajectories"] == result.training_trajectories == len(mine) >= 10
    # the same samples: the same data hash, and predictions equal to 1e-6 K
    assert info["training"]["data_sha256"] == offline.data_hash == result.data_hash
    depth = 18
    diff = np.abs(registered.predict_windows(_windows(validation, depth))
                  - offline.predict_windows(_windows(validation, depth)))  # fmt: skip
    assert diff.max() < 1e-6
    expected = mae_per_step(offline, validation).mean(axis=1)
    assert result.validation_mae_per_step_c == pytest.approx(expected, abs=1e-9)
    assert info["validation"]["mae_per_step_c"] == pytest.approx(expected, abs=1e-9)
    assert result.minutes["not_counted"]["connection_lost"] > 0  # the Zürich train's 40 min


def _windows(trajectories, depth):
    from trainclimate.predict.evaluate import validation_windows

    return validation_windows(trajectories, depth)


def test_a_fit_worse_than_the_active_model_is_refused_unless_forced(demo_day_database, capsys):
    # the active model has seen the validation coaches too: a fit without them is worse on them
    everything = [t for c in sorted(demo.coach_ids()) for t in by_hand(demo_day_database, c)]
    insider = TransientPredictor(12, 6).fit(everything)
    with demo_day_database.transaction() as s:
        s.execute(update(PredictorModel).values(artifact=predictor_bytes(insider)))
    code, out, err = call(capsys, "model", "retrain", "--db", demo_day_database.url, "--json")
    assert code == 2 and out == ""
    assert "worse than the active version 1" in err and len(err.splitlines()) == 1
    with demo_day_database.transaction() as s:
        assert s.scalar(select(PredictorModel.version).order_by(PredictorModel.version.desc())) == 1
    code, out, err = call(
        capsys, "model", "retrain", "--db", demo_day_database.url, "--force", "--json"
    )
    assert code == 0, err
    d = json.loads(out)
    assert (d["version"], d["state"], d["active_version"]) == (2, "candidate", 1)
    assert np.mean(d["validation_mae_per_step_c"]) > np.mean(d["active_validation_mae_per_step_c"])


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--days", "1", "--since", "2024-11-28"], "not both"),
        (["--days", "0"], "--days must be positive"),
        (["--since", "yesterday-ish"], "not a date"),
        (["--coaches", "NOPE-A,D1-A"], "no telemetry of coach 'NOPE-A'"),
        (["--coaches", "D1-A"], "need at least two"),
        (["--since", "2030-01-01"], "is empty"),
        (["--days", "0.05"], "too little data"),
    ],
)
def test_every_refusal_is_one_line_and_registers_nothing(demo_day_database, capsys, argv, needle):
    code, out, err = call(capsys, "model", "retrain", "--db", demo_day_database.url, *argv)
    assert code == 2 and out == "" and len(err.splitlines()) == 1 and needle in err, err
    with demo_day_database.transaction() as s:
        assert s.scalar(select(PredictorModel.version).order_by(PredictorModel.version.desc())) == 1


def test_no_telemetry_is_refused(tmp_path):
    url = f"sqlite:///{tmp_path / 'empty.db'}"
    migrate(url)
    database = Database(url)
    with pytest.raises(RetrainError, match="no telemetry is stored"):
        retrain(database)
    database.dispose()


#: A retraining in a process of its own (``force``: registered whatever its error), printing its
#: peak of traced memory (Python's and numpy's allocations), bytes.
PEAK = """
import sys, tracemalloc
from trainclimate.service.retrain import retrain
from trainclimate.service.store.db import Database
db = Database(sys.argv[1])
tracemalloc.start()
result = retrain(db, force=True)
print(tracemalloc.get_traced_memory()[1], result.window[0].isoformat())
"""


def test_a_stray_row_a_year_old_leaves_the_retraining_flat(demo_day, tmp_path):
    """A gateway's wrong clock stored a row a year before the rest (its first batch: nothing to
    hold it against). The retraining reads its default window, not everything back to that row:
    the peak memory with the row is the peak without it (it read 20 coaches × a year of minutes
    before), and so is the window."""
    peaks, starts = {}, {}
    for name in ("clean", "stray"):
        path = tmp_path / f"{name}.db"
        shutil.copy(demo_day, path)
        url = f"sqlite:///{path}"
        if name == "stray":
            database = Database(url)
            with database.transaction() as s:
                newest = s.scalars(
                    select(Telemetry)
                    .where(Telemetry.coach_id == "D1-A")
                    .order_by(Telemetry.time.desc())
                ).first()
                columns = {c.key: getattr(newest, c.key) for c in Telemetry.__table__.columns}
                del columns["id"]
                s.add(Telemetry(**{**columns, "time": newest.time - timedelta(days=365)}))
            database.dispose()
        done = subprocess.run(
            [sys.executable, "-c", PEAK, url],
            capture_output=True,
            text=True,
            env=os.environ,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        peak, start = done.stdout.split()
        peaks[name], starts[name] = int(peak), start
    assert starts["stray"] == starts["clean"]
    assert peaks["stray"] / peaks["clean"] < 1.05, peaks


def test_shadow_predictions_never_change_an_issued_setpoint(demo_day, tmp_path):
    """The same 12 periods from the same stored day, with and without a candidate (the active
    model's own file): the setpoints are identical, and the candidate's predictions equal the
    active model's own (the same samples and the same planned setpoints)."""
    runs = {}
    for name in ("plain", "shadow"):
        path = tmp_path / f"{name}.db"
        shutil.copy(demo_day, path)
        database = Database(f"sqlite:///{path}")
        with database.transaction() as s:
            start = s.scalar(select(Setpoint.tick).order_by(Setpoint.tick.desc()))
            if name == "shadow":
                v1 = s.scalar(select(PredictorModel))
                s.add(PredictorModel(version=2, method=v1.method, rho=v1.rho, horizon=v1.horizon,
                                     sampling_min=v1.sampling_min, artifact=v1.artifact,
                                     state="candidate"))  # fmt: skip
        settings = Settings(database_url=database.url)
        fleet = demo.DemoFleet(database, Scheduler(database, settings), speedup=1.0)
        for _ in range(12):
            fleet.advance()
        with database.transaction() as s:
            runs[name] = {
                (r.coach_id, r.tick): (r.t_ref_c, r.source, r.reason, r.predicted)
                for r in s.scalars(select(Setpoint).where(Setpoint.tick > start))
            }
            shadows = {
                (r.coach_id, r.tick): r.y_pred_c for r in s.scalars(select(ShadowPrediction))
            }
        database.dispose()
    plain, shadow = runs["plain"], runs["shadow"]
    assert plain.keys() == shadow.keys() and len(plain) == 12 * 20
    assert [v[:3] for v in plain.values()] == [v[:3] for v in shadow.values()]
    ddpc = {k: v for k, v in shadow.items() if v[1] == "ddpc"}
    assert ddpc and shadows.keys() == ddpc.keys()
    for key, (_, _, _, predicted) in ddpc.items():
        np.testing.assert_allclose(shadows[key], predicted["y_pred_c"], atol=1e-9)


@pytest.fixture
def app_on(demo_day_database, tmp_path):
    """The service on the copy (no demo fleet: the test advances nothing) and tokens."""
    settings = Settings(database_url=demo_day_database.url, scheduler_interval_s=0.05)
    with demo_day_database.transaction() as s:
        tokens = {
            role: {"Authorization": f"Bearer {create_token(s, role, f'test-{role}')[0]}"}
            for role in ("viewer", "operator", "admin")
        }
    return settings, tokens


def test_a_candidate_in_the_shadow_an_operator_cannot_promote_an_admin_can(
    demo_day_database, app_on
):
    settings, tokens = app_on
    retrain(demo_day_database, force=True)  # version 2, a candidate
    fleet = demo.DemoFleet(demo_day_database, Scheduler(demo_day_database, settings), speedup=1.0)
    for _ in range(3):
        fleet.advance()
    with demo_day_database.transaction() as s:
        v2 = s.scalar(select(PredictorModel).where(PredictorModel.version == 2))
        assert s.query(ShadowPrediction).filter_by(model_id=v2.id).count() > 0
    with TestClient(create_app(settings)) as client:
        models = client.get(f"{API}/models", headers=tokens["viewer"]).json()
        assert [(m["version"], m["state"], m["active"]) for m in models] == [
            (1, "active", True),
            (2, "candidate", False),
        ]
        assert len(models[1]["validation_mae_per_step_c"]) == 6
        assert len(models[1]["online_mae_per_step_c"]) == 6
        h = client.get(f"{API}/models/2/health", headers=tokens["viewer"]).json()
        assert h["state"] == "candidate" and h["predictions"] > 0
        assert h["beside"]["predictions"] == h["predictions"]  # the active model, same ticks
        url = f"{API}/models/2/activate"
        refused = client.post(url, params={"reason": "better"}, headers=tokens["operator"])
        assert refused.status_code == 403
        done = client.post(url, params={"reason": "better on the shadow"}, headers=tokens["admin"])
        assert done.status_code == 200 and done.json()["state"] == "active"
    with demo_day_database.transaction() as s:
        entry = s.scalars(select(AuditLog).where(AuditLog.action == "model.activate")).one()
        assert (entry.user_name, entry.reason, entry.detail) == (
            "test-admin",
            "better on the shadow",
            {"previous": 1},
        )
    # a restart: the promotion holds, exactly one version is active, and the next tick uses it
    with TestClient(create_app(settings)) as client:
        models = client.get(f"{API}/models", headers=tokens["viewer"]).json()
        assert [(m["version"], m["state"]) for m in models] == [(1, "retired"), (2, "active")]
    fleet = demo.DemoFleet(demo_day_database, Scheduler(demo_day_database, settings), speedup=1.0)
    tick = fleet.advance()
    with demo_day_database.transaction() as s:
        used = set(s.scalars(select(Setpoint.model_id).where(Setpoint.tick == tick)))
        assert used - {None} == {v2.id}
        with pytest.raises(IntegrityError):  # the database itself refuses a second active one
            s.execute(update(PredictorModel).values(state="active"))
            s.flush()


def test_retraining_from_the_api_runs_in_the_background(demo_day_database, app_on):
    settings, tokens = app_on
    with TestClient(create_app(settings)) as client:
        body = {"reason": "a month of winter", "force": True}
        assert client.post(f"{API}/models/retrain", json=body,
                           headers=tokens["operator"]).status_code == 403  # fmt: skip
        both = client.post(
            f"{API}/models/retrain",
            json={**body, "days": 1, "since": "2024-11-28T00:00:00Z"},
            headers=tokens["admin"],
        )
        assert both.status_code == 422 and "not both" in both.json()["detail"]
        started = client.post(f"{API}/models/retrain", json=body, headers=tokens["admin"])
        assert started.status_code == 202 and started.json()["state"] == "running"
        again = client.post(f"{API}/models/retrain", json=body, headers=tokens["admin"])
        assert again.status_code == 409
        deadline = time.monotonic() + 120
        while (status := client.get(f"{API}/models/retrain", headers=tokens["viewer"]).json())[
            "state"
        ] == "running":
            assert time.monotonic() < deadline
            time.sleep(0.2)
        assert status["state"] == "done", status
        assert status["result"]["version"] == 2 and status["requested_by"] == "test-admin"
    with demo_day_database.transaction() as s:
        assert s.scalars(select(AuditLog.action).where(AuditLog.action == "model.retrain")).all()


def test_drift_against_the_validation_error_and_the_bound():
    assert drift([0.10, 0.12], [0.05, 0.06], 1.5) == (
        "online MAE 0.110 °C is more than 1.5× the validation MAE 0.055 °C"
    )
    assert drift([0.07, 0.08], [0.05, 0.06], 1.5) is None
    assert drift([0.3, None], None, 1.5) == "online MAE 0.300 °C exceeds the bound 0.25 °C"
    assert drift([], [0.05], 1.5) is None
