"""``GET /api/v1/metrics``: the service's Prometheus metrics (:mod:`trainclimate.service.
metrics`), for a ``metrics`` token (a scraper's: it reads nothing else) or a viewer's and above."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from trainclimate.service import metrics
from trainclimate.service.api.deps import AUTH
from trainclimate.service.api.security import require_metrics
from trainclimate.service.store.tokens import Principal

router = APIRouter()
MetricsReader = Annotated[Principal, Depends(require_metrics())]


@router.get(
    "/metrics",
    tags=["health"],
    response_class=Response,
    responses={
        200: {
            "content": {metrics.CONTENT_TYPE.split(";")[0]: {"schema": {"type": "string"}}},
            "description": "the Prometheus text format (version 0.0.4)",
        },
        **AUTH,
    },
)
def get_metrics(request: Request, _: MetricsReader) -> Response:
    """This replica's metrics in the Prometheus text format: the ticks, the coaches by their
    latest decision, the setpoints, the telemetry taken and refused by transport, the MQTT feed,
    the HTTP answers, the admission and the database pool, the model's online error and drift,
    the loops and the disk; every series labelled ``replica``. No query per scrape: counts kept
    in memory (docs/deployment.md lists the series)."""
    return Response(metrics.exposition(request.app.state.metrics), media_type=metrics.CONTENT_TYPE)
