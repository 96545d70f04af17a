"""Every command that opens the service's database ends in one line and exit 2, never a
traceback, for a database it cannot use: a PostgreSQL database that does not exist (saying
``createdb NAME``), a server that does not answer, a scheme the service does not take, a URL
that is no URL, a home where the SQLite file cannot be made. A password in the URL is never
shown."""

from __future__ import annotations

import pytest

from helpers.service import PG_SKIP, PG_URL
from trainclimate.cli import main

COMMANDS = [
    ["token", "create", "--role", "viewer"],
    ["serve", "--port", "1"],
    ["retention", "--raw-days", "30"],
]


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c[0])
@pytest.mark.parametrize(
    "url, message",
    [
        (
            "SERVER/tc_no_such_database",
            "the database 'tc_no_such_database' does not exist on",
        ),
        ("postgresql://postgres:s3cret@127.0.0.1:1/x", "cannot use the database postgresql://"),
        ("mysql://u:s3cret@db/x", "unsupported database 'mysql://u:***@db/x': use sqlite:///"),
        ("not a url", "not a database URL: 'not a url'"),
    ],
)
def test_a_database_that_cannot_be_used_is_one_line(command, url, message, capsys):
    if url.startswith("SERVER"):  # a server that answers, without that database
        if not PG_URL:
            pytest.skip(PG_SKIP)
        url = url.replace("SERVER", PG_URL.rsplit("/", 1)[0])
    assert main([*command, "--db", url]) == 2
    err = capsys.readouterr().err
    if url.endswith("tc_no_such_database"):
        assert err.rstrip().endswith(
            ": create it first (createdb tc_no_such_database), then try again"
        )
    assert err.count("\n") == 1 and err.startswith("trainclimate: error: "), err
    assert message in err
    assert "s3cret" not in err and "Traceback" not in err


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c[0])
def test_a_home_that_cannot_be_made_is_one_line(command, monkeypatch, capsys):
    monkeypatch.delenv("TRAINCLIMATE_DATABASE_URL", raising=False)
    monkeypatch.setenv("TRAINCLIMATE_HOME", "/proc/trainclimate-home")
    assert main(command) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "set TRAINCLIMATE_HOME or TRAINCLIMATE_DATABASE_URL" in err
