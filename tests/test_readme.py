"""The README's command block runs as written, in a fresh home, so the docs cannot drift from the
product: every ``.venv/bin/trainclimate …`` line of it is run in a temporary directory with a
temporary ``$TRAINCLIMATE_HOME``, in order (later commands use what earlier ones wrote), with the
small-scale options listed below appended where a command has them. Each must exit 0; with
``--json`` it must print one JSON object with the keys the table promises; every ``--out`` /
``--html`` it names must exist afterwards. ``serve`` is started, must print its URL, and is
stopped; ``gateway`` runs against it. A line of the README this table does not know fails the
test: a new command needs its entry here.

Commands that cannot run small are named in :data:`ELSEWHERE` with the test that runs them at a
small scale instead.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from helpers.processes import free_port
from helpers.service import wait_for

REPO = Path(__file__).resolve().parents[1]
SCRIPT = Path(sys.executable).with_name("trainclimate")
MODEL = "models/tp.npz"  # what the README's `predictor fit` line writes

#: Options appended to keep a README command small, and the JSON keys it must print, by the
#: command's words before its first option.
SMALL: dict[str, tuple[list[str], set[str]]] = {
    "scenarios": ([], set()),
    "simulate": (["--hours", "2", "--predictor", MODEL], {"energy_kwh", "controller"}),
    "coach-params": ([], set()),
    "bench simulator": (["--coaches", "4", "--days", "0.02"], {"coach_days_per_s", "target_met"}),
    "dataset build": (["--days", "2", "--coaches", "4"], {"table", "dropped_rows"}),
    "predictor evaluate": (["--horizon", "3"], {"mae_per_step_c", "mae_per_step_deck_c"}),
    "predictor fit": ([], set()),
    "bench predictor": (["--scales", "1"], {"fit_seconds", "target_met"}),
    "experiment run": (["--predictor", MODEL], {"savings_pct", "avg_hourly_violation_k"}),
    "experiment trial": (
        ["--days", "1", "--predictor", MODEL],
        {"savings_pct", "true_savings_pct", "error_pct", "estimator"},
    ),
    "report demo": (["--predictor", MODEL, "--coaches", "1", "--hours", "2"], set()),
    "token create": ([], {"token", "role"}),
    "retention": ([], {"cutoff", "rows_deleted", "partitions_dropped", "database"}),
    "train plan D2": ([], {"plan", "pending", "activated_today", "next_switch", "history"}),
    "study fleet": (
        ["--coaches", "2", "--days", "1", "--chunk-coaches", "1", "--predictor", MODEL],
        {"coach_days", "savings_pct", "avg_hourly_violation_k", "chunks", "chunks_skipped"},
    ),
}
#: README commands run at a small scale by another test, and why not here.
ELSEWHERE = {
    "bench pipeline": "minutes at its fixed size; tests/bench/test_pipeline.py runs it small",
    "predictor study": "three sensitivity studies (minutes); tests/predict/ run them small",
    "predictor default": "fits on the whole default dataset; tests/service/test_preparation.py",
    "bench controller": "fits the default model; tests/bench/test_controller.py runs it small",
    "experiment summary": "five paired experiments (minutes); tests/analysis/ run them small",
    "bench service": "PostgreSQL, minutes; tests/bench/test_service.py runs it small",
    "calibrate": "a fit (a minute); tests/twin/test_calibration.py runs the same command",
    "bench study": "the default model and two clusters; tests/bench/test_study.py runs it small",
    "model retrain": "needs a service database with days of telemetry; "
    "tests/service/test_model_lifecycle.py runs the same command on one",
}


def readme_commands() -> list[str]:
    """The ``.venv/bin/trainclimate`` lines of the README's command block, without comments."""
    text = (REPO / "README.md").read_text()
    block = re.search(r"the `trainclimate` command line:\n\n```sh\n(.*?)```", text, re.S)
    assert block, "the README's command block is gone"
    lines = [line.split("  #")[0].strip() for line in block.group(1).splitlines()]
    return [line for line in lines if line.startswith(".venv/bin/trainclimate ")]


def kind(words: list[str]) -> str:
    """A command's words before its first option (``bench simulator``, ``token create``)."""
    head = []
    for w in words:
        if w.startswith("-") or w == ">":
            break
        head.append(w)
    return " ".join(head)


def test_every_readme_command_is_known():
    for line in readme_commands():
        k = kind(shlex.split(line)[1:])
        assert k in SMALL or k in ELSEWHERE or k in ("serve", "gateway"), (
            f"README command {k!r} has no entry in tests/test_readme.py"
        )


def test_the_readme_commands_run_as_written(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("TRAINCLIMATE_")}
    env |= {"TRAINCLIMATE_HOME": str(tmp_path / "home"), "HOME": str(tmp_path / "user")}
    work = tmp_path / "work"
    work.mkdir()
    port = free_port()
    server = None
    try:
        for line in readme_commands():
            words = shlex.split(line)[1:]
            k = kind(words)
            if k in ELSEWHERE:
                continue
            redirect = None
            if ">" in words:
                words, redirect = words[: words.index(">")], words[words.index(">") + 1]
            if k == "serve":
                if server is None:  # the first: the demo fleet; the MQTT one is checked alone
                    server = serve(words, port, env, work)
                else:
                    serve(words, free_port(), env, work).terminate()
                continue
            if k == "gateway":
                words = gateway_args(words, port, env, work)
            extra, keys = SMALL.get(k, ([], set()))
            if k == "simulate" and "--controller" not in words:
                extra = [a for a in extra if a not in ("--predictor", MODEL)]
            done = subprocess.run(
                [str(SCRIPT), *words, *extra],
                cwd=work,
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
            )
            assert done.returncode == 0, (line, done.stderr[-3000:])
            if redirect:
                (work / redirect).write_text(done.stdout)
            if "--json" in words:
                data = json.loads(done.stdout)
                assert keys <= set(data), (line, sorted(data))
            for flag in ("--out", "--html"):
                if flag in words and k != "token create":
                    assert (work / words[words.index(flag) + 1]).exists(), (line, flag)
    finally:
        if server is not None:
            server.terminate()
            server.wait(timeout=30)


def serve(words: list[str], port: int, env: dict, work: Path) -> subprocess.Popen:
    """``serve`` as written on a free port; returns once it printed its URL."""
    if "--mqtt" in words and not broker_answers():
        pytest.skip("no MQTT broker on 127.0.0.1:1883 for the README's serve --mqtt")
    log = work / f"serve-{port}.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [str(SCRIPT), *words, "--port", str(port)], cwd=work, env=env, stdout=out, stderr=out
        )
    wait_for(lambda: f"serving on http://127.0.0.1:{port}/" in log.read_text(), 60, "serve")
    assert proc.poll() is None, log.read_text()
    return proc


def gateway_args(words: list[str], port: int, env: dict, work: Path) -> list[str]:
    """The README's ``gateway`` line against the served port, with a gateway token for its
    coaches (the README's TOKEN) and a short, fast run."""
    coaches = words[words.index("--coaches") + 1]
    done = subprocess.run(
        [str(SCRIPT), "token", "create", "--role", "gateway", "--coaches", coaches, "--json"],
        cwd=work, env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    token = json.loads(done.stdout)["token"]
    words = [token if w == "TOKEN" else w for w in words]
    words[words.index("--server") + 1] = f"http://127.0.0.1:{port}"
    return [*words, "--hours", "0.2", "--speedup", "600", "--quiet"]


def broker_answers() -> bool:
    import socket

    try:
        socket.create_connection(("127.0.0.1", 1883), timeout=1).close()
        return True
    except OSError:
        return False
