"""What an attacker or a broken client probes, on SQLite and PostgreSQL: path traversal on the
dashboard's files, bodies nested deeper than any parser should follow, NaN and Infinity, ids and
reasons in any script. Each is a clear 4xx (or stored verbatim where it is valid), never a 500,
and nothing is stored that should not be."""

from __future__ import annotations

import json

import pytest

from helpers.service import API, count, flat_rows, post_rows, register, to_wire
from trainclimate.service.store.models import AuditLog, Coach, Override, Telemetry


@pytest.mark.parametrize(
    "path",
    [
        "/..%2f..%2f..%2fetc%2fpasswd",
        "/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
        "/vendor/..%2f..%2fpyproject.toml",
        "/..%5c..%5cpyproject.toml",
        "/app.js%00.html",
    ],
)
def test_no_file_outside_the_dashboard_is_served(client, path):
    reply = client.get(path)
    assert reply.status_code == (422 if "%00" in path else 404)  # a NUL: refused for any path
    assert "root:" not in reply.text and "[project]" not in reply.text


@pytest.mark.parametrize("depth", [100, 100_000])
def test_deeply_nested_bodies_are_a_4xx(client, tokens, settings, depth):
    register(client, tokens["operator"], "A")
    headers = {**tokens["operator"], "Content-Type": "application/json"}
    for path in (f"{API}/coaches/A/override", f"{API}/telemetry"):
        body = "[" * depth + "]" * depth
        reply = client.post(path, content=body, headers=headers)
        assert 400 <= reply.status_code < 500, (path, reply.status_code)
        assert "detail" in reply.json()
    assert count(settings.database_url, Override) == 0
    assert count(settings.database_url, Telemetry) == 0


@pytest.mark.parametrize("value", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_nan_and_infinity_are_refused_and_not_echoed(client, tokens, settings, value):
    op = tokens["operator"]
    register(client, op, "A")
    headers = {**op, "Content-Type": "application/json"}
    body = f'{{"t_ref_c": {value}, "duration_min": 30, "reason": "probe"}}'
    reply = client.post(f"{API}/coaches/A/override", content=body, headers=headers)
    assert reply.status_code == 422
    row = json.dumps(to_wire(flat_rows(1, 1)[0])).replace('"t_amb_c": 0.0', f'"t_amb_c": {value}')
    reply = client.post(
        f"{API}/telemetry", content=f'{{"coach_id": "A", "rows": [{row}]}}', headers=headers
    )
    assert reply.status_code == 422
    assert value not in reply.text
    assert count(settings.database_url, Override) == 0
    assert count(settings.database_url, Telemetry) == 0


def test_ids_outside_the_allowed_characters_are_refused(client, tokens, settings):
    op = tokens["operator"]
    for coach_id in ("Zürich-1", "124 A", "../124", "A\u0000", "１２４-A", "A" * 33):
        reply = register(client, op, coach_id)
        assert reply.status_code == 422, coach_id
    assert count(settings.database_url, Coach) == 0
    # a path naming such a coach is a 404 or a 422, never a 500
    for path in ("/coaches/Z%C3%BCrich-1", "/coaches/%F0%9F%9A%86/timeseries"):
        assert client.get(f"{API}{path}", headers=op).status_code in (404, 422)


def test_a_reason_in_any_script_is_stored_verbatim(client, tokens, settings):
    op = tokens["operator"]
    register(client, op, "A")
    post_rows(client, op, "A", flat_rows(1, 3))
    reason = "Tür klemmt — Fahrgäste frieren 🥶 <script>alert(1)</script> 列車"
    t_rule = client.get(f"{API}/coaches/A", headers=op).json()["t_rule_c"]
    body = {"t_ref_c": t_rule + 1.0, "duration_min": 30, "reason": reason}
    reply = client.post(f"{API}/coaches/A/override", json=body, headers=op)
    assert reply.status_code == 201, reply.text
    overrides = client.get(f"{API}/coaches/A/overrides", headers=op).json()
    assert [o["reason"] for o in overrides] == [reason]
    audit = client.get(f"{API}/audit", headers=op).json()
    assert any(e["reason"] == reason for e in audit)
    assert count(settings.database_url, AuditLog) >= 2
