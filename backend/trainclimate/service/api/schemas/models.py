"""The predictor models: the registry, retraining and a model's online health."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field, StrictBool

from trainclimate.service.api.schemas.base import CoachIds, Strict


class ModelOut(BaseModel):
    id: int
    version: int
    method: str
    rho: int
    horizon: int
    sampling_min: float | None
    state: str = Field(description="active (the controllers use it), candidate (predicting in "
                       "its shadow) or retired")  # fmt: skip
    active: bool = Field(description="state is active")
    created_at: datetime
    validation_mae_per_step_c: list[float] | None = Field(
        description="the validation MAE per step recorded with the model, °C"
    )
    online_mae_per_step_c: list[float | None] = Field(
        description="the active model's and a candidate's: its predictions' MAE per step over "
        "the 24 h up to its newest (GET /models/{version}/health), °C; empty without predictions "
        "and for a retired model (ask its health)"
    )
    info: dict = Field(description="training window and data hash, validation …")


class CoachHealth(BaseModel):
    coach_id: str
    first_step_mae_c: float | None = Field(
        description="°C, over its predictions and decks at step 1; null without a sample"
    )
    samples: int = Field(description="its (prediction, step, deck) triples with an actual")


class RetrainIn(Strict):
    reason: str = Field(min_length=1, max_length=500, examples=["the winter's first month"])
    days: float | None = Field(
        default=None,
        gt=0,
        le=366,
        description="the last N days (default: 28 without since; the window is at most 366)",
    )
    since: datetime | None = Field(default=None, description="telemetry from this time")
    coaches: CoachIds | None = Field(default=None, max_length=10_000)
    force: StrictBool = Field(
        default=False, description="register even a fit worse than the active"
    )


class RetrainStatus(BaseModel):
    state: str = Field(description="idle, running, done or failed")
    stage: str
    percent: float
    detail: str = Field(description="done: what was registered; failed: why nothing was")
    result: dict | None = Field(description="done: version, state, validation_mae_per_step_c …")
    requested_by: str | None
    reason: str | None


class ShadowBeside(BaseModel):
    mae_per_step_c: list[float | None] = Field(description="per step 1 … T, °C")
    samples: int
    predictions: int


class ModelHealth(BaseModel):
    """A predictor model's stored predictions against the telemetry that followed them: the
    predictions issued in (start, end], the ``hours`` up to the model's newest prediction tick
    (the data's clock); an actual is the row stamped t + k·Δ, left out when missing, not
    connected or not in regular mode."""

    version: int
    start: datetime | None = Field(description="null: the model never predicted")
    end: datetime | None = Field(description="the model's newest prediction tick")
    step_min: float = Field(examples=[5.0], description="Δ, the prediction step")
    bound_c: float = Field(examples=[0.25], description="the paper's bound on the predictor's MAE")
    predictions: int = Field(description="stored predictions in the window")
    samples: int = Field(description="the sum of samples_per_step")
    samples_per_step: list[int] = Field(
        description="per step 1 … T: the (prediction, deck) pairs with an actual"
    )
    mae_per_step_c: list[float | None] = Field(
        examples=[[0.12, 0.13, 0.13, 0.14, 0.14, 0.14]],
        description="per step 1 … T: the mean absolute error over every coach, prediction and "
        "deck with an actual, °C; null for a step without a sample; empty without predictions",
    )
    coaches: list[CoachHealth]
    exceeds_bound: bool = Field(description="the first-step MAE over all coaches exceeds bound_c")
    state: str = Field(description="active, candidate or retired")
    beside: ShadowBeside | None = Field(
        description="a candidate's: the issued setpoints' own predictions on the same coaches "
        "and ticks (the active model's at the time)"
    )
    validation_mae_per_step_c: list[float] | None = Field(
        description="the validation MAE per step recorded with the model, °C"
    )
    drift_factor: float = Field(description="the setting drift_factor")
    drift: bool = Field(
        description="the online MAE (mean over the steps) exceeds drift_factor × the validation "
        "MAE, or bound_c"
    )
    drift_reason: str | None = Field(description="why drift is flagged, in words")
