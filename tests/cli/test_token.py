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
