"""The alert rules of ``deploy/prometheus/alerts.yml``: valid (``promtool check rules``), each
alert tested on synthetic series (``promtool test rules alerts.test.yml``: a case that fires and
one that must not), and end to end: a real Prometheus (Debian's ``prometheus`` package, the same
as ``promtool``) scraping a running ``trainclimate serve`` fed by a real gateway emulator; the
feed stopped, the live-feed alert fires in Prometheus's API, and not before. The end-to-end run
shortens the rule's thresholds (5 min → 3 s) and Prometheus's intervals (1 s) only."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import httpx
import pytest
import yaml

from helpers.processes import CLI, free_port, token_cli
from helpers.service import wait_for

ROOT = Path(__file__).resolve().parents[2]
RULES = ROOT / "deploy" / "prometheus" / "alerts.yml"
RULE_TESTS = ROOT / "deploy" / "prometheus" / "alerts.test.yml"
PROMTOOL = shutil.which("promtool")
PROMETHEUS = shutil.which("prometheus")
NO_PROMETHEUS = "no promtool/prometheus on this machine (apt-get install prometheus; .ci/run does)"
#: What an operations team must be told about (each an alert of the rules).
REQUIRED = {
    "TrainclimateLiveFeedDown",
    "TrainclimateCoachesStale",
    "TrainclimateTicksLate",
    "TrainclimateTicksBehind",
    "TrainclimateTicksSkipped",
    "TrainclimateModelDrift",
    "TrainclimateDatabaseUnreachable",
    "TrainclimateHttp5xxRate",
    "TrainclimateMqttDisconnected",
    "TrainclimateDiskFull",
}


def alerts(path: Path = RULES) -> dict[str, dict]:
    groups = yaml.safe_load(path.read_text())["groups"]
    return {rule["alert"]: rule for group in groups for rule in group["rules"] if "alert" in rule}


def test_every_required_alert_is_there_and_tested_both_ways():
    rules = alerts()
    assert set(rules) >= REQUIRED
    cases = yaml.safe_load(RULE_TESTS.read_text())["tests"]
    checks = [c for case in cases for c in case["alert_rule_test"]]
    for name in rules:
        mine = [c for c in checks if c["alertname"] == name]
        assert any(c["exp_alerts"] for c in mine), f"{name} never fires in alerts.test.yml"
        assert any(not c["exp_alerts"] for c in mine), f"{name} is never checked silent"


@pytest.mark.skipif(PROMTOOL is None, reason=NO_PROMETHEUS)
def test_promtool_checks_the_rules_and_their_unit_tests_pass():
    check = subprocess.run([PROMTOOL, "check", "rules", str(RULES)], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    assert f"SUCCESS: {len(alerts())} rules found" in check.stdout
    done = subprocess.run(
        [PROMTOOL, "test", "rules", RULE_TESTS.name],
        cwd=RULE_TESTS.parent,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "SUCCESS" in done.stdout


def shortened_rules(tmp: Path) -> Path:
    """``alerts.yml`` with the live-feed alert's 5 min (silence and pending) as 3 s and 2 s."""
    text = RULES.read_text()
    rule = alerts()["TrainclimateLiveFeedDown"]
    assert "> 300" in rule["expr"] and rule["for"] == "5m"
    data = yaml.safe_load(text)
    for group in data["groups"]:
        for each in group["rules"]:
            if each.get("alert") == "TrainclimateLiveFeedDown":
                each["expr"] = each["expr"].replace("> 300", "> 3")
                each["for"] = "2s"
    path = tmp / "alerts.yml"
    path.write_text(yaml.safe_dump(data))
    return path


class Prometheus:
    """Debian's Prometheus on a free port, scraping ``target`` every second with ``token``."""

    def __init__(self, tmp: Path, target: str, token: str, rules: Path):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        config = {
            "global": {"scrape_interval": "1s", "evaluation_interval": "1s"},
            "rule_files": [str(rules)],
            "scrape_configs": [
                {
                    "job_name": "trainclimate",
                    "metrics_path": "/api/v1/metrics",
                    "authorization": {"type": "Bearer", "credentials": token},
                    "static_configs": [{"targets": [target]}],
                }
            ],
        }
        (tmp / "prometheus.yml").write_text(yaml.safe_dump(config))
        self.log = tmp / "prometheus.log"
        with self.log.open("wb") as out:
            self.proc = subprocess.Popen(
                [
                    PROMETHEUS,
                    f"--config.file={tmp / 'prometheus.yml'}",
                    f"--storage.tsdb.path={tmp / 'data'}",
                    f"--web.listen-address=127.0.0.1:{self.port}",
                ],
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        wait_for(self._ready, 30, "Prometheus ready")

    def _ready(self) -> bool:
        if self.proc.poll() is not None:
            pytest.fail(f"prometheus exited:\n{self.log.read_text()[-3000:]}")
        try:
            return httpx.get(f"{self.url}/-/ready", timeout=1).status_code == 200
        except httpx.TransportError:
            return False

    def query(self, expr: str) -> list[dict]:
        reply = httpx.get(f"{self.url}/api/v1/query", params={"query": expr}, timeout=5).json()
        assert reply["status"] == "success", reply
        return reply["data"]["result"]

    def alerts(self, name: str) -> list[dict]:
        reply = httpx.get(f"{self.url}/api/v1/alerts", timeout=5).json()
        return [a for a in reply["data"]["alerts"] if a["labels"]["alertname"] == name]

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.proc.kill()


@pytest.mark.skipif(PROMETHEUS is None, reason=NO_PROMETHEUS)
def test_prometheus_fires_the_live_feed_alert_when_the_feed_stops(servers, proc_env, tmp_path):
    db_url = f"sqlite:///{tmp_path / 'trainclimate.db'}"
    env = {**proc_env, "TRAINCLIMATE_METRICS_REFRESH_S": "1"}
    server = servers(db_url, "--replica-name", "e2e", env=env).start()
    metrics_token = token_cli(db_url, "metrics", proc_env)
    gateway_token = token_cli(db_url, "gateway", proc_env, "--coaches", "124-A,124-B")
    feed = subprocess.Popen(
        [*CLI, "gateway", "--server", server.url, "--coaches", "124-A,124-B", "--token",
         gateway_token, "--hours", "3", "--speedup", "60", "--json"],
        env=proc_env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    prometheus = None
    try:
        prometheus = Prometheus(
            tmp_path, f"127.0.0.1:{server.port}", metrics_token, shortened_rules(tmp_path)
        )
        # scraped, with the live coaches and their rows: the feed is up, the alert silent
        wait_for(
            lambda: prometheus.query('trainclimate_live_coaches{replica="e2e"} == 2'),
            60,
            "Prometheus to see the two live coaches",
        )
        stored = 'trainclimate_telemetry_rows_total{transport="http",outcome="stored"}'
        wait_for(lambda: prometheus.query(f"{stored} > 4"), 30, "rows stored, as scraped")
        [up] = prometheus.query('up{job="trainclimate"}')
        assert up["value"][1] == "1"
        assert prometheus.alerts("TrainclimateLiveFeedDown") == []
        feed.terminate()
        feed.wait(timeout=15)

        def firing() -> list[dict]:
            found = prometheus.alerts("TrainclimateLiveFeedDown")
            return [a for a in found if a["state"] == "firing"]

        [alert] = wait_for(firing, 60, "the live feed alert firing")
        assert alert["labels"]["severity"] == "critical"
        assert alert["annotations"]["summary"].startswith("No live telemetry for ")
    finally:
        if feed.poll() is None:
            feed.kill()
        if prometheus is not None:
            prometheus.stop()


def test_the_compose_prometheus_scrapes_the_backend_with_the_metrics_token(tmp_path):
    from trainclimate.cli import build_parser

    services = yaml.safe_load((ROOT / "docker-compose.yml").read_text())["services"]
    config = yaml.safe_load((RULES.parent / "prometheus.yml").read_text())
    mounts = {v.split(":")[1]: v.split(":")[0] for v in services["prometheus"]["volumes"]}
    assert mounts["/etc/prometheus/prometheus.yml"] == "./deploy/prometheus/prometheus.yml"
    assert mounts["/etc/prometheus/alerts.yml"] == "./deploy/prometheus/alerts.yml"
    assert config["rule_files"] == ["alerts.yml"]
    [job] = config["scrape_configs"]
    token = build_parser().parse_args(services["metrics-token"]["command"][1:])
    assert (token.command, token.role) == ("token", "metrics")
    assert job["authorization"]["credentials_file"] == token.out
    assert mounts["/run/trainclimate"] == "metrics-token"
    assert job["metrics_path"] == "/api/v1/metrics"
    backend = build_parser().parse_args(services["backend"]["command"][1:])
    assert job["static_configs"] == [{"targets": [f"backend:{backend.port}"]}]
    if PROMTOOL is None:
        pytest.skip(NO_PROMETHEUS)
    # promtool checks the configuration with its rules, the token file made to exist
    (tmp_path / "token").write_text("tc_x\n")
    job["authorization"]["credentials_file"] = str(tmp_path / "token")
    (tmp_path / "prometheus.yml").write_text(yaml.safe_dump(config))
    shutil.copy(RULES, tmp_path / "alerts.yml")
    done = subprocess.run(
        [PROMTOOL, "check", "config", "prometheus.yml"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stdout + done.stderr
