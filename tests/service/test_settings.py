"""The service's settings in one place: every setting described and documented, ``serve --help``
taken from the descriptions, a refused value one line naming its option or its variable, and the
MQTT broker read from the settings alone."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from pydantic import ValidationError

from trainclimate.cli import build_parser, main
from trainclimate.cli.service import SERVE_OPTIONS, setting_help
from trainclimate.service.adapters.mqtt import Broker
from trainclimate.service.settings import Settings, allowed, env_var

DOCS = Path(__file__).resolve().parents[2] / "docs" / "service.md"


def serve_parser() -> argparse.ArgumentParser:
    parser = build_parser()
    [commands] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return commands.choices["serve"]


def test_every_setting_has_a_description():
    for name, field in Settings.model_fields.items():
        assert field.description and field.description.strip() == field.description, name


def test_the_docs_name_every_settings_variable():
    text = DOCS.read_text()
    missing = [env_var(name) for name in Settings.model_fields if f"`{env_var(name)}`" not in text]
    assert missing == []


def test_serve_help_is_the_settings_description():
    """Each ``serve`` option that sets a setting has the setting's description as its help (with
    the default and the variable after it), so the two cannot drift apart."""
    helps = {o: a.help for a in serve_parser()._actions for o in a.option_strings}
    assert set(SERVE_OPTIONS.values()) <= set(helps)
    for name, option in SERVE_OPTIONS.items():
        if option == "--mqtt-password-file":  # a file holding the password: not the setting
            continue
        description = Settings.model_fields[name].description.removesuffix(")")
        assert helps[option].replace("%%", "%").startswith(description), option
    assert helps["--guard-days"] == setting_help("guard_days")
    assert helps["--guard-days"].endswith("(default 3; $TRAINCLIMATE_GUARD_DAYS)")
    assert "95 %% interval" in helps["--guard-days"]  # argparse prints it as 95 %
    assert helps["--speedup"].endswith("(default 1)")  # serve always sets it: no variable
    assert helps["--replica-name"].endswith(
        "(default: HOST:PID); replicas sharing one "
        "PostgreSQL database split the coaches ($TRAINCLIMATE_REPLICA_NAME)"
    )


def test_bounds_in_words():
    assert allowed("backfill_horizon_days") == "in (0, 3650] [days]"
    assert allowed("max_ahead_min") == "in (0, 1440] [min]"
    assert allowed("guard_days") == "at least 1"
    assert allowed("max_body_bytes") == "positive [bytes]"
    assert allowed("drift_factor") == "above 1"
    assert allowed("db_lock_timeout_s") == "at least 0 [s]"
    assert allowed("fleet") == ""


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--speedup", "0"], "--speedup: must be positive"),
        (["--speedup", "inf"], "--speedup: must be positive"),
        (["--max-ahead-min", "1441"], "--max-ahead-min: must be in (0, 1440] [min]"),
        (["--max-ahead-min", "nan"], "--max-ahead-min: must be in (0, 1440] [min]"),
        (["--guard-days", "0"], "--guard-days: must be at least 1"),
        (["--replica-name", ""], "--replica-name: must be 1 to 64 printable characters"),
        (["--replica-name", "a\tb"], "--replica-name: must be 1 to 64 printable characters"),
        (["--replica-name", "r" * 65], "--replica-name: must be 1 to 64 printable characters"),
        (
            ["--mqtt", "mqtt://broker", "--mqtt-ca", "/no/ca.pem"],
            "--mqtt: no CA file /no/ca.pem",
        ),
        (
            ["--mqtt", "mqtt://broker", "--mqtt-prefix", "a/#"],
            "--mqtt: the topic prefix must be non-empty, without + or #: 'a/#'",
        ),
    ],
    ids=lambda v: v if isinstance(v, str) else " ".join(v),
)
def test_serve_names_the_option_of_a_refused_value(extra, message, tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'tc.db'}"
    assert main(["serve", "--db", db, *extra]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == f"trainclimate: error: {message}\n"
    assert not (tmp_path / "tc.db").exists()  # refused before the database is touched


@pytest.mark.parametrize(
    ("variable", "value", "message"),
    [
        ("TRAINCLIMATE_GUARD_DAYS", "0", "must be at least 1"),
        ("TRAINCLIMATE_MAX_BODY_BYTES", "-1", "must be positive [bytes]"),
        ("TRAINCLIMATE_SAMPLING_MIN", "0", "must be positive"),
        ("TRAINCLIMATE_REPLICA_NAME", "a\tb", "must be 1 to 64 printable characters"),
        (
            "TRAINCLIMATE_MQTT_URL",
            "http://broker",
            "not an MQTT broker URL (mqtt://HOST[:PORT] or mqtts://…): 'http://broker'",
        ),
    ],
)
def test_serve_names_the_variable_of_a_refused_value(
    variable, value, message, tmp_path, capsys, monkeypatch
):
    """A value from the environment that no option overrode: the line names the variable (it
    was a traceback before)."""
    monkeypatch.setenv(variable, value)
    db = f"sqlite:///{tmp_path / 'tc.db'}"
    assert main(["serve", "--db", db]) == 2
    assert capsys.readouterr().err == f"trainclimate: error: {variable}: {message}\n"


def test_an_option_wins_over_its_variable(monkeypatch):
    """``--guard-days 2`` over ``TRAINCLIMATE_GUARD_DAYS=0``: the settings take the option."""
    from trainclimate.cli.service import serve_settings

    monkeypatch.setenv("TRAINCLIMATE_GUARD_DAYS", "0")
    monkeypatch.setenv("TRAINCLIMATE_MAX_AHEAD_MIN", "30")
    args = build_parser().parse_args(["serve", "--guard-days", "2", "--db", "sqlite:///x.db"])
    settings = serve_settings(args)
    assert (settings.guard_days, settings.max_ahead_min) == (2, 30.0)


def test_the_broker_is_read_from_the_settings(tmp_path):
    ca = tmp_path / "ca.pem"
    ca.write_text("")
    settings = Settings(
        mqtt_url="mqtt://svc:url%20pw@broker:1884", mqtt_ca_file=ca, mqtt_prefix="/fleet/v2/"
    )
    assert settings.broker(None, None) == Broker(
        host="broker",
        port=1884,
        tls=True,
        username="svc",
        password="url pw",
        ca_file=ca,
        prefix="fleet/v2",
    )
    admin = settings.broker("admin", "admin-pw")
    assert (admin.username, admin.password, admin.address) == (
        "admin",
        "admin-pw",
        "mqtts://broker:1884",
    )
    with pytest.raises(ValueError, match="mqtt_url is not set"):
        Settings().broker(None, None)


def test_a_bad_broker_is_refused_with_the_settings(tmp_path):
    with pytest.raises(ValidationError) as caught:
        Settings(mqtt_url="mqtt://broker", mqtt_ca_file=tmp_path / "none.pem")
    [error] = caught.value.errors()
    assert error["loc"] == ("mqtt_url",) and str(error["ctx"]["error"]).startswith("no CA file")
