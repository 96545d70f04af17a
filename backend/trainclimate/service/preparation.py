"""Getting the predictor model ready without keeping the service waiting.

A database without a model gets one in the background while the service already answers and
the coaches run under the rule-based setpoint T_rule (what they do without the layer): the
default model if it is cached on this machine, else the quick model, fitted on a quick generated
campaign (:func:`trainclimate.predict.default.startup_predictor`). It is registered as version 1,
active; the scheduler picks it up at its next tick and the layer takes over on its own.
:class:`ModelPreparation` holds how far it is, for ``GET /health`` and the dashboard.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import asdict, dataclass

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from trainclimate.service.store.db import Database
from trainclimate.service.store.models import PredictorModel

log = logging.getLogger(__name__)

#: Share of the work in each stage of a model build (generation, pipeline, fit), for the percent.
STAGES = {"generate": (0.0, 0.55), "pipeline": (0.55, 0.95), "fit": (0.95, 1.0)}
STAGE_TEXT = {
    "generate": "simulating a quick campaign",
    "pipeline": "cleaning the campaign's logs",
    "fit": "fitting the predictor model",
}


@dataclass
class Status:
    """What the service is preparing: ``state`` ``running``, ``done`` or ``failed``; ``task``,
    ``stage`` (words) and ``percent`` (0–100) while running; ``detail`` when done or failed."""

    task: str
    state: str
    stage: str
    percent: float
    detail: str = ""


def register_predictor(session, predictor, note: str) -> None:
    """Register ``predictor`` as model version 1, active (the database must have no model)."""
    from trainclimate.predict.artifact import predictor_bytes

    validation = predictor.metadata.get("validation")
    info = {k: predictor.metadata.get(k) for k in ("training", "validation", "created_utc")}
    session.add(
        PredictorModel(
            version=1,
            method=predictor.method,
            rho=predictor.rho,
            horizon=predictor.horizon,
            sampling_min=predictor.sampling_min,
            artifact=predictor_bytes(predictor, validation),
            info={**info, "source": note},
            state="active",
        )
    )


def has_model(session) -> bool:
    """Whether the database holds any predictor model."""
    return session.scalar(select(PredictorModel.id).limit(1)) is not None


class ModelPreparation:
    """Prepares the first model in a thread (:meth:`start`) and reports how far it is."""

    def __init__(self, db: Database):
        self.db = db
        self._lock = threading.Lock()
        self._status = Status("predictor model", "done", "", 100.0, "a model is registered")
        self.thread: threading.Thread | None = None

    @property
    def status(self) -> Status:
        """A copy of how far the preparation is."""
        with self._lock:
            return Status(**asdict(self._status))

    def _set(self, **changes) -> None:
        with self._lock:
            for key, value in changes.items():
                setattr(self._status, key, value)

    def start(self) -> None:
        """Start preparing the model if the database has none (else nothing to do)."""
        with self.db.transaction() as session:
            if has_model(session):
                return
        self._set(state="running", stage="looking for a cached model", percent=0.0, detail="")
        self.thread = threading.Thread(target=self.run, name="model-preparation", daemon=True)
        self.thread.start()

    def progress(self, stage: str, done: int, total: int) -> None:
        """Progress callback of the dataset build: ``stage`` and coach-days ``done``/``total``."""
        low, high = STAGES[stage]
        share = min(done / total, 1.0) if total else 1.0
        self._set(stage=STAGE_TEXT[stage], percent=round(100 * (low + share * (high - low)), 1))

    def run(self) -> None:
        """Build or load the start-up model and register it (the thread's body)."""
        from trainclimate.predict.default import startup_predictor

        try:
            predictor, which = startup_predictor(self._progress_until_fit)
            with self.db.transaction() as session:
                if not has_model(session):
                    register_predictor(session, predictor, f"{which} model, prepared at start")
        except IntegrityError:  # another replica registered it first
            pass
        except Exception as exc:
            log.exception("preparing the predictor model failed; the coaches stay on T_rule")
            self._set(state="failed", detail=str(exc).splitlines()[0] if str(exc) else repr(exc))
            return
        log.info("predictor model ready: the layer takes over at the next tick")
        self._set(state="done", stage="", percent=100.0, detail="the model is registered")

    def _progress_until_fit(self, stage: str, done: int, total: int) -> None:
        self.progress(stage, done, total)
        if stage == "pipeline" and done >= total:
            self.progress("fit", 0, 1)
