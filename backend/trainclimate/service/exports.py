"""CSV exports of what the dashboard shows: a pair comparison's windows, the fleet summary per
train and a coach's telemetry. Each is written from the same dict the JSON answer is made of, so
the CSV carries the same numbers (floats written in full, ``repr``; an empty cell for null).

Times are ISO 8601 in UTC (``…Z``), on the fleet clock (the coaches' own clock, as the API gives
it; the demo's runs years behind the wall clock). Energies in kWh, temperatures in °C, excess in
K, savings in %, power in kW, irradiance in W/m², speed in km/h.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime, timedelta
from enum import Enum
from typing import Any, Final

from starlette.responses import Response

from trainclimate.service.store.records import TimeSeries

#: The CSV's media type (RFC 4180 with UTF-8 text).
MEDIA_TYPE = "text/csv; charset=utf-8"

#: The fleet summary's per-train columns, in order (``savings_ci95_pct`` split in two).
TRAIN_COLUMNS = (
    "id",
    "name",
    "plan",
    "coaches",
    "activated",
    "deactivated",
    "start_utc",
    "end_utc",
    "meter",
    "savings_pct",
    "savings_ci95_low_pct",
    "savings_ci95_high_pct",
    "savings_ci95_reason",
    "estimator",
    "naive_savings_pct",
    "energy_activated_kwh",
    "energy_deactivated_kwh",
    "avg_hourly_violation_activated_k",
    "avg_hourly_violation_deactivated_k",
    "excluded_minutes",
    "counted_windows",
    "counted_hours",
    "days_to_target",
)
#: The telemetry columns written as the time series holds them, in order.
_SERIES_COLUMNS: Final = (
    "t_ref_c",
    "t_rule_c",
    "t_amb_c",
    "ghi_w_m2",
    "power_kw",
    "floor_power_kw",
    "occupancy_pct",
    "speed_kmh",
    "mode",
    "connected",
    "source",
)
#: A coach's telemetry columns, in order (``t_room_c`` split by deck).
TELEMETRY_COLUMNS = ("time_utc", "t_room_up_c", "t_room_mid_c", "t_room_low_c", *_SERIES_COLUMNS)


def cell(value: object) -> str:
    """One CSV cell: null empty, a float in full (``repr``), a time in ISO 8601 UTC (``…Z``;
    a naive time is taken as UTC), a bool ``true``/``false``, an enum by its value."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, datetime):
        aware = value if value.tzinfo else value.replace(tzinfo=UTC)
        return aware.astimezone(UTC).isoformat().replace("+00:00", "Z")
    if isinstance(value, Enum):
        return str(value.value)
    return str(value)


def write(header: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    """The CSV text of ``header`` and ``rows`` (CRLF line ends, as RFC 4180 has them)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(header)
    for row in rows:
        writer.writerow([cell(v) for v in row])
    return out.getvalue()


def comparison_csv(cmp: dict) -> str:
    """A pair comparison's windows (:func:`.store.comparison.comparison`), one row each: its
    start and end (UTC, fleet clock), the coach under the layer and the other, each coach's
    energy (kWh), the activated and deactivated energy (kWh), the saving (%), whether and why
    it is excluded."""
    c0, c1 = cmp["coaches"]
    width = float(cmp["window_min"])
    header = [
        "window_start_utc",
        "window_end_utc",
        "activated",
        "deactivated",
        f"energy_{c0}_kwh",
        f"energy_{c1}_kwh",
        "energy_activated_kwh",
        "energy_deactivated_kwh",
        "savings_pct",
        "excluded",
        "excluded_reason",
    ]

    def row(w: dict) -> list:
        start = w["start"]
        end = _plus_minutes(start, width)
        act = w["activated"]
        deact = None if act is None else (c1 if act == c0 else c0)
        energy = w["energy_kwh"]
        return [
            start,
            end,
            act,
            deact,
            energy.get(c0),
            energy.get(c1),
            w["energy_activated_kwh"],
            w["energy_deactivated_kwh"],
            w["savings_pct"],
            w["excluded"],
            w["excluded_reason"],
        ]

    return write(header, (row(w) for w in cmp["windows"]))


def fleet_csv(summary: dict) -> str:
    """The fleet summary per train (:func:`.store.fleet_summary.summary`), one row each in
    :data:`TRAIN_COLUMNS`: its pair, range (UTC, fleet clock), trial estimate with its 95 %
    interval (%), energies (kWh), violations (K), excluded minutes and counted windows."""

    def row(t: dict) -> list:
        ci = t.get("savings_ci95_pct") or [None, None]
        values = {
            **t,
            "coaches": " ".join(t["coaches"]),
            "start_utc": t["start"],
            "end_utc": t["end"],
            "savings_ci95_low_pct": ci[0],
            "savings_ci95_high_pct": ci[1],
        }
        return [values.get(k) for k in TRAIN_COLUMNS]

    return write(TRAIN_COLUMNS, (row(t) for t in summary["trains"]))


def telemetry_csv(ts: TimeSeries) -> str:
    """A coach's telemetry (:func:`.store.queries.timeseries`), one row a minute in
    :data:`TELEMETRY_COLUMNS`: the minute's end (UTC, fleet clock), the decks' temperatures
    (°C), setpoints (°C), ambient (°C), irradiance (W/m²), power (kW), occupancy (%), speed
    (km/h), HVAC mode, link and the setpoint's source."""

    def row(i: int) -> list:
        decks = list(ts["t_room_c"][i] or [None, None, None])
        return [ts["time"][i], *decks, *(ts[k][i] for k in _SERIES_COLUMNS)]

    return write(TELEMETRY_COLUMNS, (row(i) for i in range(len(ts["time"]))))


def response(text: str, *name: str) -> Response:
    """``text`` as a CSV download (``Content-Disposition: attachment``) named after ``name``."""
    disposition = f'attachment; filename="{filename(*name)}"'
    return Response(text, media_type=MEDIA_TYPE, headers={"Content-Disposition": disposition})


#: How a CSV route documents its answer in the OpenAPI spec.
CSV_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {"content": {"text/csv": {}}, "description": "CSV, a header row first"}
}


def filename(*parts: str) -> str:
    """A download's file name from ``parts`` (anything but letters, digits, ``-`` and ``_``
    replaced by ``_``), ending ``.csv``."""
    return "-".join(re.sub(r"[^A-Za-z0-9_-]", "_", p) for p in parts) + ".csv"


def _plus_minutes(start: datetime | str, minutes: float) -> datetime:
    """``start`` plus ``minutes`` [min] (an ISO string read first)."""
    when = datetime.fromisoformat(start) if isinstance(start, str) else start
    return when + timedelta(minutes=minutes)
