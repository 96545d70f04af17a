"""Every place the product writes is created with its parents, or refused in one line that names
the path and what to do (a new user's machine has no ``~/.cache``, a user's path can be wrong)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from helpers.cli import call
from trainclimate.paths import StorageError, home, sqlite_file, writable_dir, writable_file
from trainclimate.service.store.db import migrate


def test_a_directory_is_made_with_its_parents(tmp_path):
    target = tmp_path / "a" / "b" / "c"
    assert writable_dir(target, "the thing") == target and target.is_dir()
    assert writable_dir(target, "the thing") == target  # again: nothing to do


def test_a_file_in_the_way_is_one_line_naming_the_path_and_the_remedy(tmp_path):
    (tmp_path / "a").write_text("a file")
    with pytest.raises(StorageError) as raised:
        writable_dir(tmp_path / "a" / "models", "the model store")
    message = str(raised.value)
    assert "\n" not in message
    assert str(tmp_path / "a") in message and "the model store" in message
    assert "set TRAINCLIMATE_HOME or TRAINCLIMATE_DATABASE_URL" in message


def test_a_file_target_gets_its_directory_and_a_directory_is_not_a_file(tmp_path):
    target = tmp_path / "x" / "y" / "report.html"
    assert writable_file(target, "the report") == target and target.parent.is_dir()
    with pytest.raises(StorageError, match="it is a directory"):
        writable_file(tmp_path / "x", "the report")


def test_a_directory_that_cannot_be_written_is_refused(tmp_path, monkeypatch):
    # as root (CI) a read-only mode is no obstacle, so the access check is what is tested
    locked = tmp_path / "locked"
    locked.mkdir()
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != locked)
    with pytest.raises(StorageError, match=f"cannot write the store in {locked}: permission"):
        writable_dir(locked, "the store")
    with pytest.raises(StorageError, match="permission denied"):
        writable_file(locked / "f.txt", "the file")


def test_home_follows_the_environment_and_defaults_under_the_user_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("TRAINCLIMATE_HOME", str(tmp_path / "h"))
    assert home() == tmp_path / "h"
    monkeypatch.delenv("TRAINCLIMATE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "user"))
    assert home() == tmp_path / "user" / ".cache" / "trainclimate"


@pytest.mark.parametrize(
    ("url", "path"),
    [
        ("sqlite:////var/x/t.db", "/var/x/t.db"),
        ("sqlite:///rel/t.db?mode=rwc", "rel/t.db"),
        ("sqlite:///:memory:", None),
        ("sqlite://", None),
        ("postgresql://h/db", None),
    ],
)
def test_the_file_of_a_sqlite_url(url, path):
    assert sqlite_file(url) == (None if path is None else Path(path))


def test_migrating_a_sqlite_database_creates_its_directory(tmp_path):
    url = f"sqlite:///{tmp_path / 'new' / 'deeper' / 'trainclimate.db'}"
    migrate(url)
    assert (tmp_path / "new" / "deeper" / "trainclimate.db").is_file()


def test_token_create_on_the_default_database_of_a_home_that_does_not_exist(
    capsys, monkeypatch, tmp_path
):
    monkeypatch.setenv("TRAINCLIMATE_HOME", str(tmp_path / "fresh" / "home"))
    monkeypatch.delenv("TRAINCLIMATE_DATABASE_URL", raising=False)
    code, out, err = call(capsys, "token", "create", "--role", "viewer", "--json")
    assert code == 0, err
    assert json.loads(out)["token"] and (tmp_path / "fresh" / "home" / "trainclimate.db").exists()


def test_a_home_that_is_a_file_is_a_one_line_error_with_the_remedy(capsys, monkeypatch, tmp_path):
    blocker = tmp_path / "home"
    blocker.write_text("not a directory")
    monkeypatch.setenv("TRAINCLIMATE_HOME", str(blocker))
    monkeypatch.delenv("TRAINCLIMATE_DATABASE_URL", raising=False)
    code, out, err = call(capsys, "token", "create", "--role", "viewer")
    assert code == 2 and out == ""
    [line] = err.strip().splitlines()
    assert line.startswith("trainclimate: error: cannot create")
    assert str(blocker) in line and "set TRAINCLIMATE_HOME or TRAINCLIMATE_DATABASE_URL" in line


@pytest.mark.slow  # a `serve` process
def test_serve_with_a_home_in_the_way_exits_2_before_serving(tmp_path):
    blocker = tmp_path / "home"
    blocker.write_text("not a directory")
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    env["TRAINCLIMATE_HOME"] = str(blocker)
    run = subprocess.run(
        [sys.executable, "-m", "trainclimate.cli", "serve", "--port", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2, run.stderr
    assert run.stderr.strip().splitlines()[-1].startswith("trainclimate: error: cannot create")


@pytest.mark.parametrize(
    "command",
    [
        "simulate --scenario parked-heating-nov --hours 0.5 --out {f}/x.parquet",
        "token create --role viewer --out {f}/token",
        "experiment run --scenario parked-heating-nov --html {f}/r.html",
        "dataset build --days 1 --coaches 1 --out {f}/data",
        "report demo --out {f}/demo",
    ],
)
def test_an_output_path_under_a_file_is_refused_before_any_work(capsys, tmp_path, command):
    blocker = tmp_path / "file"
    blocker.write_text("in the way")
    code, out, err = call(capsys, *command.format(f=blocker).split())
    assert code == 2 and out == ""
    [line] = err.strip().splitlines()
    assert f"a file is in the way ({blocker}); choose another path" in line


def test_outputs_are_written_under_directories_that_do_not_exist_yet(capsys, tmp_path):
    target = tmp_path / "a" / "b" / "run.parquet"
    simulate = f"simulate --scenario parked-heating-nov --hours 0.5 --out {target}"
    code, _, err = call(capsys, *simulate.split())
    assert code == 0, err
    assert target.is_file()
    token = tmp_path / "c" / "d" / "token"
    create = f"token create --role viewer --out {token} --db sqlite:///{tmp_path / 'e' / 't.db'}"
    code, _, err = call(capsys, *create.split())
    assert code == 0, err
    assert token.read_text().startswith("tc_")
