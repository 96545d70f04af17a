"""``train plan``: the plan view of a train on the service's database, a change audited as the
CLI user, and one-line refusals with exit code 2 (unknown train, bad arguments, a plan on a train
without a pair)."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from sqlalchemy import select

from helpers.cli import call, call_json
from trainclimate.cli import train
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import AuditLog, Coach, Telemetry, Train


@pytest.fixture
def db_url(tmp_path) -> str:
    """A migrated SQLite database with train T (T-A activated, T-B not; telemetry up to
    2024-11-28 07:00 Zurich time) and train S of one coach."""
    url = f"sqlite:///{tmp_path / 'tc.db'}"
    migrate(url)
    db = Database(url)
    with db.transaction() as s:
        s.add_all([Train(id="T", name="T"), Train(id="S", name="S")])
        s.flush()
        s.add_all(
            [
                Coach(id="T-A", train_id="T", ddpc_active=True),
                Coach(id="T-B", train_id="T"),
                Coach(id="S-A", train_id="S", ddpc_active=True),
            ]
        )
        s.flush()
        s.add(Telemetry(coach_id="T-A", time=datetime(2024, 11, 28, 6, tzinfo=UTC)))
    db.dispose()
    return url


def test_the_plan_is_shown_and_changed(db_url, capsys, monkeypatch):
    monkeypatch.setattr(train.getpass, "getuser", lambda: "alice")
    view = call_json(capsys, "train", "plan", "T", "--db", db_url)
    assert (view["train_id"], view["plan"], view["pending"], view["activated_today"]) == (
        "T",
        "fixed",
        None,
        "T-A",
    )
    assert view["clock"] == "2024-11-28T06:00:00Z"
    view = call_json(
        capsys, "train", "plan", "T", "--plan", "randomized", "--switch-hour", "4", "--seed",
        "11", "--reason", "a month's trial", "--db", db_url,
    )  # fmt: skip
    assert view["plan"] == "fixed"
    pending = view["pending"]
    assert (pending["plan"], pending["switch_hour"], pending["seed"]) == ("randomized", 4, 11)
    assert pending["effective_from"] == "2024-11-29T03:00:00Z"  # 04:00 Zurich time
    assert pending["created_by"] == "cli:alice"
    assert "not mid-day" in view["message"]
    code, out, err = call(capsys, "train", "plan", "T", "--db", db_url)
    assert code == 0 and err == ""
    assert out.startswith("train T: the fixed plan is in force") and "randomized" in out
    db = Database(db_url)
    with db.transaction() as s:
        entry = s.scalars(select(AuditLog)).one()
        assert (entry.user_name, entry.role, entry.action, entry.target, entry.reason) == (
            "cli:alice",
            "admin",
            "train.plan",
            "T",
            "a month's trial",
        )
        assert entry.detail["after"]["plan"] == "randomized"
    db.dispose()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["Z"], "no train 'Z'"),
        (["Z", "--plan", "fixed", "--reason", "x"], "no train 'Z'"),
        (["S", "--plan", "alternate", "--reason", "x"], "train S has 1 coach(es)"),
        (["T", "--plan", "weekly", "--reason", "x"], "--plan 'weekly': expected one of"),
        (["T", "--plan", "alternate", "--switch-hour", "24", "--reason", "x"], "0–23"),
        (["T", "--plan", "alternate", "--seed", "-1", "--reason", "x"], "--seed -1"),
        (["T", "--plan", "alternate"], "--plan needs --reason TEXT"),
        (["T", "--plan", "alternate", "--reason", " "], "--plan needs --reason TEXT"),
        (["T", "--switch-hour", "5"], "--switch-hour changes the plan: give --plan too"),
        (["T", "--plan", "alternate", "--switch-hour", "x", "--reason", "x"], "invalid int"),
    ],
)
def test_refusals_are_one_line_and_exit_2(db_url, capsys, args, message):
    code, out, err = call(capsys, "train", "plan", *args, "--db", db_url)
    assert code == 2 and out == ""
    assert err.startswith("trainclimate: error: ") and message in err
    assert len(err.strip().splitlines()) == 1
