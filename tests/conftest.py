"""Suite-wide guard: no test may build the default or quick fleet dataset (≈ 2.5 min, ≈ 20 s) or
touch the user's cache. Every test runs with ``$TRAINCLIMATE_HOME`` in a temporary directory and
``trainclimate.data.cache.default_dataset`` and ``quick_dataset`` replaced by a failure; tests that
need data build a small dataset themselves.

The tests' small predictor, fitted once a session for every directory (:mod:`helpers.training`
says on what): ``training_trajectories``, ``small_predictor`` and ``small_predictor_file``.

And the ``slow`` marker of whole files and of the tests that start service processes, and the
``postgresql`` marker of the tests run against the PostgreSQL server: ``make check`` runs ``-m
"not slow and not postgresql"``, ``make test`` everything, the slow files first."""

from pathlib import Path
from types import SimpleNamespace

import pytest

from helpers import training
from helpers.service import PG_SKIP
from trainclimate.data import cache
from trainclimate.predict import TransientPredictor
from trainclimate.predict.artifact import save_predictor


@pytest.fixture(autouse=True, scope="session")
def _no_default_dataset(tmp_path_factory):
    def refuse(*args, **kwargs):
        raise AssertionError("a test asked for the default dataset")

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TRAINCLIMATE_HOME", str(tmp_path_factory.mktemp("home")))
        mp.setattr(cache, "default_dataset", refuse)
        mp.setattr(cache, "quick_dataset", refuse)
        yield


@pytest.fixture(scope="session")
def training_trajectories() -> list[SimpleNamespace]:
    """The small predictor's 5-min training trajectories (:func:`helpers.training.trajectories`)."""
    return training.trajectories()


@pytest.fixture(scope="session")
def small_predictor(training_trajectories) -> TransientPredictor:
    """The Transient Predictor at the controller's setting (5 min, ρ = 12, T = 6), fitted on
    :func:`training_trajectories` in ≈ 1.5–3 s; never the default predictor (the guard above
    forbids the default dataset). Shared by the session: no test may change it."""
    return TransientPredictor(training.RHO, training.HORIZON).fit(training_trajectories)


@pytest.fixture(scope="session")
def small_predictor_file(small_predictor, tmp_path_factory) -> Path:
    """:func:`small_predictor` saved, for the commands and the service that read a model file."""
    return save_predictor(small_predictor, tmp_path_factory.mktemp("model") / "transient.npz")


#: Test files marked ``slow`` whole (paths under tests/): those driving a real browser, service
#: processes, brokers, Prometheus or Dask clusters, the README's commands, the wheel; and those
#: whose simulations or data take seconds a test (closed-loop runs, the paper's experiments, a
#: generated fleet, a dataset built for the CLI, calibration, the demo fleet, retraining, fuzzing
#: the API, the load, calibration, study and replica benchmarks).
SLOW_FILES = (
    "analysis/test_experiment.py",
    "analysis/test_experiment_report.py",
    "analysis/test_paper_conditions.py",
    "bench/test_calibration.py",
    "bench/test_load.py",
    "bench/test_replicas.py",
    "bench/test_study.py",
    "control/test_cli_simulate.py",
    "control/test_closed_loop.py",
    "control/test_simulate.py",
    "data/test_fleetlogs.py",
    "predict/test_cli_predictor.py",
    "predict/test_real_data.py",
    "service/api/test_schemathesis.py",
    "service/test_alerts.py",
    "service/test_compose.py",
    "service/test_concurrent_writes.py",
    "service/test_dashboard.py",
    "service/test_dashboard_access.py",
    "service/test_dashboard_status.py",
    "service/test_dashboard_storage.py",
    "service/test_dashboard_tokens.py",
    "service/test_demo.py",
    "service/test_docs_pages.py",
    "service/test_feed_liveness.py",
    "service/test_gateway_backoff.py",
    "service/test_model_lifecycle.py",
    "service/test_mqtt.py",
    "service/test_processes.py",
    "service/test_replica_failover.py",
    "service/test_replica_pause.py",
    "service/test_wheel.py",
    "sim/test_plausibility.py",
    "study/test_study.py",
    "test_readme.py",
    "twin/test_calibration.py",
)
#: Fixtures that make a test ``slow`` wherever it is: ``trainclimate serve`` processes
#: (``servers``), a simulated and processed coach-day (``clean_day``).
SLOW_FIXTURES = frozenset({"servers", "clean_day"})


def _on_postgresql(item) -> bool:
    """Whether a test runs against the PostgreSQL server: a fixture's ``postgresql`` variant
    (``db_url``'s), or a test skipped without the server."""
    callspec = getattr(item, "callspec", None)
    params = callspec.params.values() if callspec is not None else ()
    if any(isinstance(value, str) and value == "postgresql" for value in params):
        return True
    return any(m.kwargs.get("reason") == PG_SKIP for m in item.iter_markers("skipif"))


def pytest_collection_modifyitems(config, items):
    """Mark ``slow`` the tests of :data:`SLOW_FILES` and those using :data:`SLOW_FIXTURES`,
    ``postgresql`` those run against the PostgreSQL server; and
    order the files for ``--dist loadfile`` (each file on one worker, so that its module
    fixtures are built once; the files handed out in this order): the slow files first, then
    those with a slow test, then the rest, each file's tests in their order. The long files
    start early, and the short ones fill the end of a run on both workers."""
    here = Path(__file__).parent
    missing = [name for name in SLOW_FILES if not (here / name).is_file()]
    if missing:
        raise pytest.UsageError(f"tests/conftest.py SLOW_FILES names no file: {missing}")
    slow_files = {here / name for name in SLOW_FILES}
    with_slow_tests = set()
    for item in items:
        if item.path in slow_files or SLOW_FIXTURES.intersection(item.fixturenames):
            item.add_marker(pytest.mark.slow)
        if _on_postgresql(item):
            item.add_marker(pytest.mark.postgresql)
        if item.get_closest_marker("slow"):
            with_slow_tests.add(item.path)
    items.sort(key=lambda item: (item.path not in slow_files, item.path not in with_slow_tests))
