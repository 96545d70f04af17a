"""Calling the command line in-process, as the CLI tests do."""

import json

from trainclimate.cli import main

#: The keys ``simulate --json`` documents.
SIMULATE_KEYS = (
    "energy_kwh",
    "avg_hourly_violation_k",
    "discomfort_kh",
    "mean_power_kw",
    "hours",
    "controller",
    "scenario",
)


def call(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def call_json(capsys, *argv):
    code, out, err = call(capsys, *argv, "--json")
    assert code == 0, err
    return json.loads(out)
