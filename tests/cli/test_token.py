"""``token create --out FILE``: the token file is readable by its owner only, also when a file
of another mode was there before, and the token is not printed."""

from __future__ import annotations

import json

from trainclimate.cli import main


def test_a_token_file_is_owner_only(tmp_path, capsys):
    out = tmp_path / "secrets" / "gateway.token"
    out.parent.mkdir()
    out.write_text("old\n")
    out.chmod(0o644)
    db = f"sqlite:///{tmp_path / 'tc.db'}"
    assert (
        main(["token", "create", "--role", "viewer", "--db", db, "--out", str(out), "--json"]) == 0
    )
    printed = json.loads(capsys.readouterr().out)
    assert printed["token"] is None and printed["file"] == str(out)
    assert out.stat().st_mode & 0o777 == 0o600
    assert out.read_text().startswith("tc_")


def test_token_create_errors_are_one_line(tmp_path, capsys):
    """An expiry too short to use (0.00001 days printed a traceback: the token expired before
    it was stored), out of range, or a name the users table cannot hold: exit 2 with one line,
    and no token."""
    db = f"sqlite:///{tmp_path / 'tc.db'}"
    for extra, message in (
        (["--expires", "0.00001"], "--expires takes a number of days in [0.000694, 3650]"),
        (["--expires", "nan"], "--expires takes"),
        (["--expires", "1e308"], "--expires takes"),
        (["--name", "x" * 49], "--name must be 1 to 48 printable characters"),
        (["--name", "tab\there"], "--name must be"),
    ):
        assert main(["token", "create", "--role", "viewer", "--db", db, *extra]) == 2, extra
        captured = capsys.readouterr()
        assert captured.out == ""
        assert captured.err.count("\n") == 1 and message in captured.err, captured.err
    assert main(["token", "create", "--role", "viewer", "--db", db, "--expires", "0.0007"]) == 0


def test_serve_refuses_a_backfill_horizon_out_of_range(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'tc.db'}"
    for days in ("0", "-1", "nan", "3651"):
        assert main(["serve", "--db", db, "--backfill-horizon-days", days]) == 2, days
        err = capsys.readouterr().err
        assert err == "trainclimate: error: --backfill-horizon-days: must be in (0, 3650] [days]\n"


def test_serve_refuses_forwarded_allow_ips_that_are_not_addresses(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'tc.db'}"
    for ips, bad in (
        ("proxy.local", "proxy.local"),
        ("10.0.0.1,*", "*"),
        ("10.0.0/33", "10.0.0/33"),
    ):
        assert main(["serve", "--db", db, "--forwarded-allow-ips", ips]) == 2, ips
        err = capsys.readouterr().err
        assert err == (
            f"trainclimate: error: --forwarded-allow-ips: {bad!r} is not an IP address or network\n"
        )
