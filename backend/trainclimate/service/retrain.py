"""Retraining the prediction model from the service's own telemetry, as a candidate.

The stored 1-minute telemetry is cut into trajectories with the data pipeline's conventions
(:mod:`trainclimate.data.pipeline`): the row stamped t is the minute (t − 1 min, t], so the
pipeline's minute m takes y from the row stamped m and u, d from the row stamped m + 1 min; a
minute counts only in regular mode, with the link up and its setpoint not overridden (an
operator's override, or a tick whose setpoint was one); short gaps of missing rows are
interpolated as the pipeline does, anything else splits the trajectory; pieces are down-sampled
to the model's period. The coaches are split as the pipeline's evaluation splits them (the last
quarter, in sorted order, validate). The Transient Predictor is fitted in one streaming pass over
the training coaches, read one at a time.

**Memory.** The window is bounded: by default the :data:`DEFAULT_DAYS` up to the newest row, at
most :data:`MAX_DAYS` whatever is asked, so a stray row (a gateway's clock set to 2000) outside it
is never read. What is held at once is one coach's window as the pipeline's 1-minute table (about
0.5 kB per minute of the window, however few rows it holds: 20 MB for 28 days, 0.25 GB for
:data:`MAX_DAYS`), the validation coaches' trajectories (5-min samples) and the predictor's
streaming sums (of a fixed size); a coach's rows outside the window, or another coach's, cost
nothing. Measured peaks (tracemalloc) on one simulated day of the 20 demo coaches: 24 MB with
``days=2``, 26 MB with 28, 73 MB with 112. ``tests/service/test_model_lifecycle.py`` holds the
peak with a stray row a year old equal to the peak without it.

The fit is judged against the active model on the same validation trajectories (MAE per step,
Section IV.A). It is registered as a new version in state ``candidate`` — with its training
window, data hash, trajectory count and validation MAE per step — unless there are too few data
or it is worse than the active model (mean MAE over the steps); ``force`` registers it anyway.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from types import SimpleNamespace

import numpy as np
import pandas as pd
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from trainclimate.data.pipeline import (
    CARRIED,
    POWER,
    STANDING,
    STANDING_KMH,
    Counts,
    PipelineSettings,
    downsample,
    piece_trajectory,
    segment,
)
from trainclimate.data.trajectory import D_NAMES, U_NAMES, Y_NAMES, Trajectory
from trainclimate.predict import PredictorDataError, TransientPredictor
from trainclimate.predict.artifact import load_predictor_bytes, predictor_bytes
from trainclimate.predict.evaluate import held_out_coaches, mae_per_step
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import Override, PredictorModel, Setpoint, Telemetry
from trainclimate.service.store.telemetry import load_frame

log = logging.getLogger(__name__)

#: The fewest training trajectories a retraining accepts.
MIN_TRAJECTORIES = 10
#: The window read when neither ``days`` nor ``start`` is given: the last four weeks. [days]
DEFAULT_DAYS = 28.0
#: The longest window read, whatever is asked. [days]
MAX_DAYS = 366.0


class RetrainError(ValueError):
    """A retraining that registers nothing (too little data, a worse fit, bad arguments)."""


@dataclass
class RetrainResult:
    """What :func:`retrain` did (``version`` None: nothing registered)."""

    version: int | None
    state: str | None
    trajectories: int
    training_trajectories: int
    validation_coaches: list[str]
    validation_mae_per_step_c: list[float]
    active_version: int | None
    active_validation_mae_per_step_c: list[float] | None
    window: tuple[datetime, datetime]
    data_hash: str
    minutes: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {
            "version": self.version,
            "state": self.state,
            "trajectories": self.trajectories,
            "training_trajectories": self.training_trajectories,
            "validation_coaches": self.validation_coaches,
            "validation_mae_per_step_c": self.validation_mae_per_step_c,
            "active_version": self.active_version,
            "active_validation_mae_per_step_c": self.active_validation_mae_per_step_c,
            "start": self.window[0].isoformat(),
            "end": self.window[1].isoformat(),
            "data_hash": self.data_hash,
            "minutes": self.minutes,
        }


def overridden_minutes(session: Session, coach_id: str, start, end, period_min: float):
    """The minute labels (UTC, the pipeline's: the minute [m, m + 1 min)) whose setpoint was
    overridden: an operator's override in force, or a tick whose setpoint was one."""
    out = set()
    overrides = session.execute(
        select(Override.starts_at, Override.ends_at, Override.cancelled_at).where(
            Override.coach_id == coach_id, Override.ends_at > start, Override.starts_at < end
        )
    ).all()
    for a, b, cancelled in overrides:
        stop = min(b, cancelled) if cancelled is not None else b
        out.update(pd.date_range(pd.Timestamp(a).ceil("1min"), stop, freq="1min", inclusive="left"))
    ticks = session.scalars(
        select(Setpoint.tick).where(
            Setpoint.coach_id == coach_id,
            Setpoint.source == "override",
            Setpoint.tick >= start,
            Setpoint.tick < end,
        )
    ).all()
    for t in ticks:
        out.update(pd.date_range(t, periods=round(period_min), freq="1min"))
    return out


def coach_minutes(frame: pd.DataFrame, start, end, excluded: set) -> tuple[pd.DataFrame, dict]:
    """A coach's telemetry rows (:func:`~trainclimate.service.store.telemetry.load_frame`) as the
    pipeline's 1-min table on [start, end) (see the module docstring), and the minutes that do
    not count, by reason."""
    grid = pd.date_range(pd.Timestamp(start).ceil("1min"), end, freq="1min", inclusive="left")
    rows = frame[~frame.index.duplicated()]
    now = rows.reindex(grid)  # the row stamped m: y measured by m
    after = rows.reindex(grid + pd.Timedelta(minutes=1))  # the row stamped m + 1: u, d over it
    minutes = pd.DataFrame(index=grid)
    for col in Y_NAMES:
        minutes[col] = now[col].to_numpy(float)
    for col in (*U_NAMES, *D_NAMES):
        minutes[col] = after[col].to_numpy(float)
    minutes[POWER] = after["power_kw"].to_numpy(float)
    speed = minutes["speed_kmh"].to_numpy(float)
    minutes[STANDING] = np.where(np.isnan(speed), np.nan, speed < STANDING_KMH)
    present = after["mode"].notna().to_numpy()
    regular = (after["mode"] == "regular").to_numpy()
    connected = after["connected"].fillna(False).astype(bool).to_numpy()
    overridden = grid.isin(list(excluded))
    ok = present & regular & connected & ~overridden
    # a known other state splits a trajectory (0); a missing row may be a short gap (NaN)
    minutes["regular"] = np.where(ok, 1.0, np.where(present, 0.0, np.nan))
    reasons = {
        "missing": int((~present).sum()),
        "not_regular": int((present & ~regular).sum()),
        "connection_lost": int((present & regular & ~connected).sum()),
        "overridden": int((present & regular & connected & overridden).sum()),
    }
    return minutes.reindex(columns=[*Y_NAMES, *U_NAMES, *D_NAMES, *CARRIED, "regular"]), reasons


def coach_trajectories(
    session: Session,
    coach_id: str,
    start,
    end,
    sampling_min: int,
    counts: Counts,
    reasons: dict,
    period_min: float,
) -> list[Trajectory]:
    """One coach's trajectories at ``sampling_min`` from its telemetry in [start, end)."""
    frame = load_frame(session, coach_id, start, end + pd.Timedelta(minutes=1))
    if frame.empty:
        return []
    excluded = overridden_minutes(session, coach_id, start, end, period_min)
    minutes, why = coach_minutes(frame, start, end, excluded)
    for k, v in why.items():
        reasons[k] = reasons.get(k, 0) + v
    out = []
    for piece in segment(minutes, PipelineSettings(), counts):
        block = downsample(piece, sampling_min)
        if len(block) < 2:
            continue
        meta = {"campaign": "service", "train": "", "coach": coach_id}
        out.append(piece_trajectory(block, meta, sampling_min))
    return out


def retrain(
    db: Database,
    *,
    start: datetime | None = None,
    end: datetime | None = None,
    days: float | None = None,
    coaches: list[str] | None = None,
    sampling_min: int = 5,
    rho: int = 12,
    horizon: int = 6,
    force: bool = False,
    period_min: float = 5.0,
    progress: Callable[[str, int, int], None] | None = None,
) -> RetrainResult:
    """Fit a candidate model on the stored telemetry and register it (see the module docstring).

    Parameters
    ----------
    db : Database
        The service's database.
    start, end : datetime, optional
        The training window (default: ``days`` up to the newest telemetry row); at most
        :data:`MAX_DAYS` long.
    days : float, optional
        The window's length up to ``end`` (default :data:`DEFAULT_DAYS` without ``start``). [days]
    coaches : list of str, optional
        The coaches to use (default: every coach with telemetry in the window).
    sampling_min, rho, horizon : int
        The model's period (min), lead-in ρ and horizon T (samples).
    force : bool
        Register even a fit worse than the active model's.
    period_min : float
        The controller's period: an overridden tick's setpoint holds that long. [min]
    progress : callable, optional
        ``progress(stage, done, total)``: ``"read"`` coaches, ``"fit"``, ``"validate"``.

    Returns
    -------
    RetrainResult

    Raises
    ------
    RetrainError
        Too few trajectories or validation windows, no coach, a window longer than
        :data:`MAX_DAYS`, or a fit worse than the active model's without ``force`` (nothing is
        registered).
    """
    report = progress or (lambda *a: None)
    if days is not None and not 0 < days <= MAX_DAYS:
        raise RetrainError(f"days must be within (0, {MAX_DAYS:g}]: {days:g}")
    with db.transaction() as s:
        newest = s.scalar(select(func.max(Telemetry.time)))
        if newest is None:
            raise RetrainError("no telemetry is stored: nothing to retrain on")
        end = end or newest
        if start is None:
            start = end - pd.Timedelta(days=days or DEFAULT_DAYS)
        if end - start > pd.Timedelta(days=MAX_DAYS):
            raise RetrainError(
                f"the window {start:%Y-%m-%d} … {end:%Y-%m-%d} is longer than {MAX_DAYS:g} "
                "days: retrain on a shorter one"
            )
        stored = sorted(
            s.scalars(
                select(Telemetry.coach_id)
                .where(Telemetry.time > start, Telemetry.time <= end)
                .distinct()
            )
        )
    if start >= end:
        raise RetrainError(f"the window {start:%Y-%m-%d %H:%M} … {end:%Y-%m-%d %H:%M} is empty")
    wanted = stored if not coaches else [c for c in coaches if c in stored]
    missing = sorted(set(coaches or []) - set(stored))
    if missing:
        raise RetrainError(f"no telemetry of coach {missing[0]!r} in the window")
    if len(wanted) < 2:
        raise RetrainError(
            f"{len(wanted)} coach(es) with telemetry in the window: training and validation "
            "need at least two"
        )
    held = held_out_coaches([SimpleNamespace(campaign="service", coach=c) for c in wanted])
    training = [c for c in wanted if c not in held]
    counts = Counts()
    reasons: dict[str, int] = {}

    def read(coach_id: str) -> list[Trajectory]:
        with db.transaction() as s:
            return coach_trajectories(
                s, coach_id, start, end, sampling_min, counts, reasons, period_min
            )

    validation = []
    for i, c in enumerate(held):
        validation += read(c)
        report("read", i + 1, len(wanted))
    n_train = 0

    def stream() -> Iterator[Trajectory]:
        nonlocal n_train
        for i, c in enumerate(training):
            for t in read(c):
                n_train += 1
                yield t
            report("read", len(held) + i + 1, len(wanted))

    predictor = TransientPredictor(rho, horizon)
    try:
        predictor.fit(stream())
    except PredictorDataError as exc:
        raise RetrainError(f"too little data to fit: {exc}") from None
    if n_train < MIN_TRAJECTORIES:
        raise RetrainError(
            f"{n_train} training trajectories in the window (at least {MIN_TRAJECTORIES}): "
            "retrain on a longer window"
        )
    report("validate", 0, 1)
    try:
        mine = mae_per_step(predictor, validation).mean(axis=1)
    except PredictorDataError as exc:
        raise RetrainError(f"too little validation data: {exc}") from None
    with db.transaction() as s:
        active = s.scalar(select(PredictorModel).where(PredictorModel.state == "active"))
        theirs = None
        if active is not None:
            current = load_predictor_bytes(active.artifact)
            if (current.rho, current.horizon) == (rho, horizon):
                theirs = mae_per_step(current, validation).mean(axis=1)
        result = RetrainResult(
            version=None,
            state=None,
            trajectories=n_train + len(validation),
            training_trajectories=n_train,
            validation_coaches=held,
            validation_mae_per_step_c=[float(v) for v in mine],
            active_version=active.version if active is not None else None,
            active_validation_mae_per_step_c=None if theirs is None else [float(v) for v in theirs],
            window=(start, end),
            data_hash=predictor.data_hash,
            minutes={"not_counted": reasons, "repaired": dict(counts.repaired),
                     "dropped": dict(counts.dropped)},
        )  # fmt: skip
        if theirs is not None and mine.mean() > theirs.mean() and not force:
            raise RetrainError(
                f"the retrained model is worse than the active version {active.version} on the "
                f"same validation coaches (mean MAE {mine.mean():.3f} against "
                f"{theirs.mean():.3f} °C); nothing registered (--force registers it anyway)"
            )
        version = (s.scalar(select(func.max(PredictorModel.version))) or 0) + 1
        validation_info = {
            "mae_per_step_c": result.validation_mae_per_step_c,
            "coaches": held,
            "active_version": result.active_version,
            "active_mae_per_step_c": result.active_validation_mae_per_step_c,
        }
        s.add(
            PredictorModel(
                version=version,
                method=predictor.method,
                rho=rho,
                horizon=horizon,
                sampling_min=sampling_min,
                artifact=predictor_bytes(predictor, validation_info),
                info={
                    "source": "retrained on the service's telemetry",
                    "training": {
                        "start": start.isoformat(),
                        "end": end.isoformat(),
                        "coaches": training,
                        "trajectories": n_train,
                        "data_sha256": result.data_hash,
                        "minutes": result.minutes,
                    },
                    "validation": validation_info,
                },
                state="candidate",
            )
        )
        result.version, result.state = version, "candidate"
    return result


class RetrainJob:
    """A retraining in a background thread (``POST /models/retrain``), one at a time, with its
    progress: ``state`` idle, running, done or failed; ``stage`` and ``percent`` while running;
    when finished, ``result`` (:meth:`RetrainResult.to_dict`) or ``detail`` (why nothing was
    registered); who asked and why."""

    def __init__(self, db: Database, period_min: float):
        self.db = db
        self.period_min = period_min
        self._lock = threading.Lock()
        self._status: dict = {"state": "idle", "stage": "", "percent": 0.0, "detail": "",
                              "result": None, "requested_by": None, "reason": None}  # fmt: skip
        self.thread: threading.Thread | None = None

    @property
    def status(self) -> dict:
        """A copy of the job's progress."""
        with self._lock:
            return dict(self._status)

    def start(self, who: str, reason: str, **options) -> bool:
        """Start a retraining with :func:`retrain`'s ``options``; False if one is running."""
        with self._lock:
            if self._status["state"] == "running":
                return False
            self._status.update(
                state="running", stage="reading telemetry", percent=0.0, detail="", result=None
            )
            self._status.update(requested_by=who, reason=reason)
        self.thread = threading.Thread(
            target=self._run, kwargs=options, name="model-retrain", daemon=True
        )
        self.thread.start()
        return True

    def _progress(self, stage: str, done: int, total: int) -> None:
        with self._lock:
            if stage == "read":
                self._status.update(
                    stage="reading telemetry", percent=round(90.0 * done / total, 1)
                )
            else:
                self._status.update(stage="validating", percent=95.0)

    def _run(self, **options) -> None:
        try:
            result = retrain(
                self.db, period_min=self.period_min, progress=self._progress, **options
            )
        except RetrainError as exc:
            self._finish(state="failed", detail=str(exc))
        except Exception as exc:  # the service runs on; the job says what went wrong
            log.exception("retraining failed")
            self._finish(state="failed", detail=f"{type(exc).__name__}: {exc}")
        else:
            self._finish(state="done", result=result.to_dict(),
                         detail=f"version {result.version} registered as a candidate")  # fmt: skip

    def _finish(self, **changes) -> None:
        with self._lock:
            self._status.update(stage="", percent=100.0, **changes)
