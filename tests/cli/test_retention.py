"""``retention``: the command line drops the raw telemetry older than ``--raw-days`` from the
service's database, keeps the window rollups and prints its report (``--json``); a number of days
below 1 is a usage error (exit 2)."""

from __future__ import annotations

import json
import os
import subprocess
from datetime import datetime, timedelta

import pytest
from sqlalchemy import func, select

from helpers.cli import call
from helpers.processes import CLI
from helpers.service import flat_row
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import Coach, Telemetry, Train, WindowRollup, utcnow
from trainclimate.service.store.telemetry import insert_rows


def test_retention_on_sqlite(tmp_path):
    url = f"sqlite:///{tmp_path / 'tc.db'}"
    migrate(url)
    db = Database(url)
    now = utcnow().replace(second=0, microsecond=0)
    old = [flat_row(now - timedelta(days=40, minutes=m)) for m in range(3)]
    recent = [flat_row(now - timedelta(days=10, minutes=m)) for m in range(2)]
    with db.transaction() as s:
        s.add(Train(id="T", name="T"))
        s.flush()
        s.add(Coach(id="T-A", train_id="T"))
        s.flush()
        assert insert_rows(s, "T-A", old + recent) == 5
        windows = s.scalar(select(func.count()).select_from(WindowRollup))
    assert windows >= 2  # the old rows' and the recent rows' windows
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    env["TRAINCLIMATE_HOME"] = str(tmp_path / "home")
    done = subprocess.run(
        [*CLI, "retention", "--raw-days", "30", "--db", url, "--json"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    cutoff = datetime.fromisoformat(report.pop("cutoff"))
    assert now - timedelta(days=30) < cutoff < utcnow() - timedelta(days=30)
    assert report == {
        "partitions_dropped": [],
        "rows_dropped": 0,
        "rows_deleted": 3,
        "database": "sqlite",
        "partitions_created": [],
    }
    with db.transaction() as s:
        assert sorted(s.scalars(select(Telemetry.time))) == sorted(r["time"] for r in recent)
        assert s.scalar(select(func.count()).select_from(WindowRollup)) == windows  # all kept
    db.dispose()


@pytest.mark.parametrize("days", ["0", "-3"])
def test_fewer_than_one_day_is_a_usage_error(days, capsys, tmp_path):
    url = f"sqlite:///{tmp_path / 'tc.db'}"
    code, out, err = call(capsys, "retention", "--raw-days", days, "--db", url)
    assert (code, out) == (2, "")
    assert (
        err.strip()
        == f"trainclimate: error: --raw-days {days}: keep at least 1 day of raw telemetry"
    )
