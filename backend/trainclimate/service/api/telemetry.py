"""The live feed's push: a gateway's batch of 1-minute telemetry rows for one coach (the pull,
the coach's setpoint now, is in :mod:`.coaches`)."""

from __future__ import annotations

from fastapi import APIRouter

from trainclimate.service.api import schemas
from trainclimate.service.api.deps import AUTH, DB, NOT_FOUND, GatewayOrOperatorTelemetry
from trainclimate.service.store import commands

router = APIRouter()


@router.post(
    "/telemetry",
    response_model=schemas.TelemetryAccepted,
    tags=["live feed"],
    responses={**AUTH, **NOT_FOUND},
)
def post_telemetry(batch: schemas.TelemetryBatch, s: DB, _: GatewayOrOperatorTelemetry) -> dict:
    """A gateway's batch of 1-minute rows for one coach; rows already stored are skipped. A
    gateway token may send it for the coaches of its scope."""
    rows = [_telemetry_row(r) for r in batch.rows]
    stored, dup = commands.ingest(s, batch.coach_id, rows)
    return {"received": len(rows), "stored": stored, "duplicates": dup}


def _telemetry_row(r: schemas.TelemetryRow) -> dict:
    up, mid, low = r.t_room_c
    return {
        "time": r.time,
        "t_room_up_c": up,
        "t_room_mid_c": mid,
        "t_room_low_c": low,
        "t_ref_c": r.t_ref_c,
        "t_rule_c": r.t_rule_c,
        "t_amb_c": r.t_amb_c,
        "ghi_w_m2": r.ghi_w_m2,
        "q_gt_w_m2": r.q_gt_w_m2,
        "q_gs_w_m2": r.q_gs_w_m2,
        "occupancy_pct": r.occupancy_pct,
        "speed_kmh": r.speed_kmh,
        "power_kw": r.power_kw,
        "mode": r.mode,
        "connected": r.connected,
    }
