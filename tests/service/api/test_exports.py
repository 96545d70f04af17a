"""The CSV exports on SQLite and on PostgreSQL: a pair comparison's windows, the fleet summary per
train and a coach's telemetry carry the same numbers as the JSON over the same range, as
``text/csv`` downloads, for a viewer (401 without a token); and how the dashboard's files are
served: gzip, ``Cache-Control`` (versioned files a year, the page revalidated) and a CSP that
lets Plotly.js draw its PNG download (``img-src … blob:``)."""

from __future__ import annotations

import csv
import io
from datetime import datetime, timedelta

import pytest

from helpers.service import (
    API,
    at,
    decided,
    flat_rows,
    post_rows,
    register,
    shared_coach_model,  # noqa: F401  (autouse)
)
from trainclimate.service.api.hardening import CONTENT_SECURITY_POLICY

RANGE = {"start": (at(180) - timedelta(hours=3)).isoformat(), "end": at(180).isoformat()}


def _pairs(client, op) -> None:
    """Two trains over three hours: E1 (A 8 kW, B 10 kW: 20 % in every window) and E2 (A 9 kW,
    B 10 kW with its link lost at T0 + 44: the window 30 … 60 excluded)."""
    for train in ("E1", "E2"):
        assert register(client, op, f"{train}-A", train, active=True).status_code == 201
        assert register(client, op, f"{train}-B", train, active=False).status_code == 201
        decided(client, f"{train}-A", 0, 175)
        decided(client, f"{train}-B", 0, 175, "rule", "inactive")
    assert post_rows(client, op, "E1-A", flat_rows(1, 180, power_kw=8.0)).status_code == 200
    assert post_rows(client, op, "E1-B", flat_rows(1, 180)).status_code == 200
    assert post_rows(client, op, "E2-A", flat_rows(1, 180, power_kw=9.0)).status_code == 200
    rows = flat_rows(1, 180)
    rows[43]["connected"] = False  # T0 + 44
    assert post_rows(client, op, "E2-B", rows).status_code == 200


def _csv(reply) -> list[dict]:
    assert reply.status_code == 200, reply.text
    assert reply.headers["content-type"] == "text/csv; charset=utf-8"
    assert reply.headers["content-disposition"].startswith("attachment; filename=")
    return list(csv.DictReader(io.StringIO(reply.text)))


def _num(text: str) -> float | None:
    return None if text == "" else float(text)


def _time(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00"))


def test_the_comparison_csv_has_the_json_windows(client, tokens):
    _pairs(client, tokens["operator"])
    viewer = tokens["viewer"]
    for train in ("E1", "E2"):
        url = f"{API}/trains/{train}/comparison"
        cmp = client.get(url, params=RANGE, headers=viewer).json()
        rows = _csv(client.get(f"{url}.csv", params=RANGE, headers=viewer))
        assert len(rows) == len(cmp["windows"]) == 6
        for row, w in zip(rows, cmp["windows"], strict=True):
            assert _time(row["window_start_utc"]) == _time(w["start"])
            assert _time(row["window_end_utc"]) - _time(w["start"]) == timedelta(minutes=30)
            assert row["activated"] == (w["activated"] or "")
            assert row["deactivated"] == ("" if w["activated"] is None else f"{train}-B")
            for coach in cmp["coaches"]:
                assert _num(row[f"energy_{coach}_kwh"]) == w["energy_kwh"][coach]
            for k in ("energy_activated_kwh", "energy_deactivated_kwh", "savings_pct"):
                assert _num(row[k]) == w[k], (train, k)
            assert row["excluded"] == ("true" if w["excluded"] else "false")
            assert row["excluded_reason"] == (w["excluded_reason"] or "")
    # by hand: E1 saves 20 % in every window; E2's window 30 … 60 is excluded (a lost link)
    e1 = _csv(client.get(f"{API}/trains/E1/comparison.csv", params=RANGE, headers=viewer))
    assert [_num(r["savings_pct"]) for r in e1] == pytest.approx([20.0] * 6)
    e2 = _csv(client.get(f"{API}/trains/E2/comparison.csv", params=RANGE, headers=viewer))
    assert [r["excluded_reason"] for r in e2] == ["", "disconnected", "", "", "", ""]
    assert e2[1]["savings_pct"] == ""


def test_the_fleet_csv_has_the_json_trains(client, tokens):
    _pairs(client, tokens["operator"])
    viewer = tokens["viewer"]
    summary = client.get(f"{API}/fleet/summary", params={"hours": 3}, headers=viewer).json()
    reply = client.get(f"{API}/fleet/summary.csv", params={"hours": 3}, headers=viewer)
    assert 'filename="fleet-summary-3h.csv"' in reply.headers["content-disposition"]
    rows = {r["id"]: r for r in _csv(reply)}
    assert sorted(rows) == ["E1", "E2"]
    for t in summary["trains"]:
        row = rows[t["id"]]
        assert (row["activated"], row["deactivated"], row["plan"]) == (
            t["activated"],
            t["deactivated"],
            t["plan"],
        )
        assert row["coaches"].split() == t["coaches"]
        assert _time(row["start_utc"]) == _time(t["start"])
        assert _time(row["end_utc"]) == _time(t["end"])
        ci = t["savings_ci95_pct"] or [None, None]
        assert [_num(row["savings_ci95_low_pct"]), _num(row["savings_ci95_high_pct"])] == ci
        for k in (
            "savings_pct",
            "naive_savings_pct",
            "energy_activated_kwh",
            "energy_deactivated_kwh",
            "avg_hourly_violation_activated_k",
            "avg_hourly_violation_deactivated_k",
            "excluded_minutes",
            "counted_windows",
            "counted_hours",
            "days_to_target",
        ):
            assert _num(row[k]) == t[k], (t["id"], k)
    assert _num(rows["E1"]["savings_pct"]) == pytest.approx(20.0)
    assert _num(rows["E2"]["excluded_minutes"]) == 30.0


def test_the_telemetry_csv_has_the_json_rows_over_the_range(client, tokens):
    _pairs(client, tokens["operator"])
    viewer = tokens["viewer"]
    span = {"start": at(60).isoformat(), "end": at(120).isoformat()}
    url = f"{API}/coaches/E2-B/timeseries"
    ts = client.get(url, params=span, headers=viewer).json()
    rows = _csv(client.get(f"{url}.csv", params=span, headers=viewer))
    assert len(rows) == len(ts["time"]) == 60  # (T0 + 60, T0 + 120]
    for i, row in enumerate(rows):
        assert _time(row["time_utc"]) == _time(ts["time"][i])
        decks = [_num(row[f"t_room_{d}_c"]) for d in ("up", "mid", "low")]
        assert decks == ts["t_room_c"][i]
        for k in ("t_ref_c", "t_rule_c", "t_amb_c", "ghi_w_m2", "power_kw", "floor_power_kw"):
            assert _num(row[k]) == ts[k][i], (i, k)
        assert row["mode"] == ts["mode"][i]
        assert row["connected"] == ("true" if ts["connected"][i] else "false")
        assert row["source"] == (ts["source"][i] or "")
    assert _num(rows[0]["power_kw"]) == 10.0


def test_the_exports_need_a_viewer_and_refuse_unknown_parameters(client, tokens):
    _pairs(client, tokens["operator"])
    for url in (
        f"{API}/trains/E1/comparison.csv",
        f"{API}/fleet/summary.csv",
        f"{API}/coaches/E1-A/timeseries.csv",
    ):
        assert client.get(url).status_code == 401, url
        assert client.get(url, params={"format": "x"}, headers=tokens["viewer"]).status_code == 422
    assert (
        client.get(f"{API}/trains/NOPE/comparison.csv", headers=tokens["viewer"]).status_code == 404
    )
    assert (
        client.get(f"{API}/coaches/NOPE/timeseries.csv", headers=tokens["viewer"]).status_code
        == 404
    )


def test_dashboard_files_are_gzipped_versioned_and_cached(client, tokens):
    page = client.get("/", headers={"Accept-Encoding": "gzip"})
    assert page.status_code == 200
    assert page.headers["content-encoding"] == "gzip"
    assert page.headers["cache-control"] == "no-cache"
    assert page.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
    assert "img-src 'self' data: blob:" in CONTENT_SECURITY_POLICY
    versioned = [
        p for p in ("app.js", "style.css", "vendor/plotly.min.js") if f'"{p}?v=' in page.text
    ]
    assert versioned == ["app.js", "style.css", "vendor/plotly.min.js"]
    for name in versioned:
        start = page.text.index(f'"{name}?v=') + 1
        url = "/" + page.text[start : page.text.index('"', start)]
        reply = client.get(url, headers={"Accept-Encoding": "gzip"})
        assert reply.status_code == 200, url
        assert reply.headers["cache-control"] == "public, max-age=31536000, immutable"
        assert reply.headers["content-encoding"] == "gzip"
    plain = client.get("/app.js")
    assert plain.headers["cache-control"] == "no-cache"
    assert (
        client.get("/app.js", headers={"If-None-Match": plain.headers["etag"]}).status_code == 304
    )
    # the API's answers stay uncached, gzipped when large
    coaches = client.get(f"{API}/coaches", headers={**tokens["viewer"], "Accept-Encoding": "gzip"})
    assert coaches.headers["cache-control"] == "no-store"
