"""The live feed's push: a gateway's batch of 1-minute telemetry rows for one coach (the pull,
the coach's setpoint now, is in :mod:`.coaches`)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from trainclimate.service.api.deps import (
    AUTH,
    CONFLICT,
    DB,
    NOT_FOUND,
    GatewayOrOperatorTelemetry,
)
from trainclimate.service.api.schemas.telemetry import TelemetryAccepted, TelemetryBatch
from trainclimate.service.store import commands
from trainclimate.service.store.telemetry import from_wire

router = APIRouter()


@router.post(
    "/telemetry",
    response_model=TelemetryAccepted,
    tags=["live feed"],
    responses={**AUTH, **NOT_FOUND, **CONFLICT},
)
def post_telemetry(
    batch: TelemetryBatch, request: Request, s: DB, _: GatewayOrOperatorTelemetry
) -> dict:
    """A gateway's batch of 1-minute rows for one coach; rows already stored are skipped. A
    gateway token may send it for the coaches of its scope. 409 for a coach of the demo
    fleet; 422 for a batch with a row older than the backfill horizon (its coach's newest row,
    stored or sent, less 7 days by default), naming the first such row (counted in
    ``GET /health``'s ``telemetry_refused``)."""
    rows = [from_wire(r.model_dump()) for r in batch.rows]
    stored, dup = commands.ingest(s, batch.coach_id, rows, request.app.state.backfill)
    request.app.state.metrics.telemetry_stored("http", stored, dup)
    return {"received": len(rows), "stored": stored, "duplicates": dup}
