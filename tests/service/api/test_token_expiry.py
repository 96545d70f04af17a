"""Tokens that expire: ``token create --expires DAYS`` and ``POST /tokens`` with
``expires_in_days`` set the expiry, ``GET /tokens`` shows it, the audit log records it, and a token
past it no longer authenticates (401)."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import update

from helpers.service import API
from trainclimate import cli
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import ApiToken


def _expire(url: str, prefix: str) -> None:
    """Move a token's expiry into the past, as time would."""
    db = Database(url)
    with db.transaction() as s:
        past = datetime.now(UTC) - timedelta(seconds=1)
        s.execute(update(ApiToken).where(ApiToken.prefix == prefix).values(expires_at=past))
    db.dispose()


def test_an_api_token_with_an_expiry_works_until_it_passes(client, tokens, settings):
    body = {"role": "viewer", "name": "visitor", "expires_in_days": 2}
    created = client.post(f"{API}/tokens", json=body, headers=tokens["admin"])
    assert created.status_code == 201, created.text
    expires = datetime.fromisoformat(created.json()["expires_at"])
    assert abs(expires - (datetime.now(UTC) + timedelta(days=2))) < timedelta(minutes=1)
    listed = client.get(f"{API}/tokens", headers=tokens["admin"]).json()
    [row] = [t for t in listed if t["user"] == "visitor"]
    assert datetime.fromisoformat(row["expires_at"]) == expires
    audit = client.get(f"{API}/audit", headers=tokens["admin"]).json()
    assert any(a["action"] == "token.create" and "expires_at" in json.dumps(a) for a in audit)
    headers = {"Authorization": f"Bearer {created.json()['token']}"}
    assert client.get(f"{API}/coaches", headers=headers).status_code == 200
    _expire(settings.database_url, row["prefix"])
    assert client.get(f"{API}/coaches", headers=headers).status_code == 401


@pytest.mark.parametrize("days", [0, -1, 4000, 1e-320, 0.0005])
def test_an_expiry_outside_a_sane_range_is_422(client, tokens, days):
    body = {"role": "viewer", "expires_in_days": days}
    assert client.post(f"{API}/tokens", json=body, headers=tokens["admin"]).status_code == 422


def test_token_create_expires(client, settings, capsys):
    argv = ["token", "create", "--role", "viewer", "--db", settings.database_url, "--json"]
    assert cli.main([*argv, "--expires", "0.5"]) == 0
    out = json.loads(capsys.readouterr().out)
    expires = datetime.fromisoformat(out["expires_at"])
    assert abs(expires - (datetime.now(UTC) + timedelta(hours=12))) < timedelta(minutes=1)
    assert cli.main([*argv, "--expires", "0"]) == 2
    assert "--expires takes a number of days" in capsys.readouterr().err
