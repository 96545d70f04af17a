"""The FastAPI application: the API, the dashboard's static files, and the loops behind them.

At start (the lifespan): the Alembic migrations are applied, the telemetry partitions of this
month and the next two are created where missing (PostgreSQL, :mod:`.store.partitions`), the
``--predictor FILE`` model is registered if the database has none, the demo fleet is registered
if asked for, and threads start: the live fleet's loop, with ``--fleet demo`` the demo fleet,
with ``--mqtt URL`` the MQTT feed (:mod:`trainclimate.service.adapters.mqtt`) and with
``--mqtt-dynsec`` the sweep of the gateways' broker clients
(:mod:`trainclimate.service.adapters.dynsec`), and, if the database still has no model, its
preparation in the background (:mod:`trainclimate.service.preparation`; the coaches run under
T_rule until it is ready). They stop with the server. Before the threads start, what exists by
then (the app, the libraries, the model) is frozen out of the garbage collector's full passes
(``gc.freeze``), and thawed when the server stops; the collector runs less often meanwhile
(:data:`GC_THRESHOLDS`).
"""

from __future__ import annotations

import gc
import json
import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from datetime import timedelta

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.middleware.gzip import GZipMiddleware
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import OperationalError, SQLAlchemyError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError
from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

from trainclimate import __version__
from trainclimate.service import api, dashboard_files, docpages, metrics
from trainclimate.service.adapters import demo
from trainclimate.service.adapters.dynsec import BrokerClients, DynsecError
from trainclimate.service.adapters.mqtt import MqttBridge
from trainclimate.service.api import spec
from trainclimate.service.api.hardening import (
    DATABASE_RETRY_AFTER_S,
    OVERLOAD_RETRY_AFTER_S,
    Admission,
    AuthFailureThrottle,
    BodySizeLimit,
    FailureCounter,
    RefuseNul,
    SecurityHeaders,
    Slots,
    pace_threads,
)
from trainclimate.service.api.observe import Observe
from trainclimate.service.api.retry import RetryConflicts, database_error
from trainclimate.service.api.security import valid_authorization
from trainclimate.service.preparation import ModelPreparation, has_model, register_predictor
from trainclimate.service.retrain import RetrainJob
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.settings import Settings
from trainclimate.service.store import partitions
from trainclimate.service.store.cache import ReadCache
from trainclimate.service.store.commands import Backfill
from trainclimate.service.store.db import Database, head_revision, migrate
from trainclimate.service.store.models import utcnow
from trainclimate.sim.params import load_params
from trainclimate.twin import validity

log = logging.getLogger(__name__)
#: The garbage collector's thresholds while the server runs (Python's: 700, 10, 10). A new 30-day
#: fleet summary at 450 trains allocates ≈ 45 000 objects: at 700 the collector ran ≈ 65 young
#: passes and, every other request, a full pass over the read cache's ≈ 330 000 objects
#: (37 ms), ≈ 27 ms per request in all; at 50 000 it costs ≈ 1 ms (measured with
#: ``gc.callbacks``). The young generation then holds at most 50 000 objects more.
GC_THRESHOLDS = (50_000, 20, 10)


def ensure_partitions(db: Database) -> None:
    """Create the telemetry partitions of this month and the next
    :data:`~.store.partitions.AHEAD_MONTHS` where missing (PostgreSQL). A failure — another
    replica creating them at the same moment, a lock not granted — is logged and the service
    starts all the same: a row without its month's partition goes to the default partition."""
    try:
        with db.transaction() as session:
            created = partitions.ensure_ahead(session, utcnow())
    except SQLAlchemyError:
        log.exception("creating the telemetry partitions failed; rows go to the default one")
        return
    if created:
        log.info("telemetry partitions created: %s", ", ".join(created))


def register_model_file(session, settings: Settings) -> None:
    """With ``--predictor FILE``: register that model as version 1 (active) if the database has
    none. Without, :class:`~trainclimate.service.preparation.ModelPreparation` prepares one."""
    if settings.predictor_path is None or has_model(session):
        return
    from trainclimate.predict.artifact import load_predictor

    register_predictor(session, load_predictor(settings.predictor_path), "--predictor file")


@asynccontextmanager
async def lifespan(app: FastAPI):
    """Migrate, register the model file and the demo fleet, start the loops (see the module
    docstring); stop them and close the database when the server stops."""
    settings: Settings = app.state.settings
    migrate(settings.database_url)
    app.state.migrations_head = head_revision()
    # the threads running the sync routes, and a pooled connection for each (store/db.py)
    pace_threads(settings.worker_threads)
    db = Database(
        settings.database_url,
        settings.worker_threads,
        settings.db_lock_timeout_s,
        settings.db_idle_in_transaction_s,
        application_name=f"trainclimate:{settings.replica_name}",
    )
    ensure_partitions(db)
    with db.transaction() as session:
        register_model_file(session, settings)
        if settings.fleet == "demo":
            demo.register(session)
    preparation = ModelPreparation(db)
    preparation.start()
    scheduler = Scheduler(db, settings, app.state.metrics)
    app.state.db, app.state.scheduler, app.state.preparation = db, scheduler, preparation
    app.state.retrain = RetrainJob(db, settings.sampling_min)
    app.state.mqtt = mqtt_bridge(db, settings, app.state.backfill)
    if app.state.mqtt is not None:
        scheduler.listeners.append(app.state.mqtt.publish_setpoints)
        app.state.mqtt.start()
    stop = app.state.stop = threading.Event()  # set: every loop of this replica stops
    threads = [threading.Thread(target=scheduler.run_live, args=(stop,), name="live-loop")]
    app.state.broker_clients = broker_clients(settings)
    if app.state.broker_clients is not None:
        sweep = app.state.broker_clients.run
        threads.append(threading.Thread(target=sweep, args=(db, stop), name="mqtt-dynsec"))
    scheduler.beat("live", scheduler.period_s)  # counted as running from its start
    if settings.fleet == "demo":
        coach = load_params(settings.demo_coach_params) if settings.demo_coach_params else None
        record = validity.record_of_file(settings.demo_coach_params)
        where = f"coach parameter file {settings.demo_coach_params}"
        validated = validity.validated_range(record, where)
        unvalidated = validity.savings_warning(record, where)
        if unvalidated:
            log.warning("the demo fleet's coaches: %s", unvalidated)
        fleet = demo.DemoFleet(
            db, scheduler, settings.speedup, coach_params=coach, validated_t_amb_c=validated
        )
        threads.append(threading.Thread(target=fleet.run, args=(stop,), name="demo-fleet"))
        scheduler.beat(demo.FLEET, scheduler.period_s / settings.speedup)
    # what is built by now lives as long as the server: kept out of the collector's full passes,
    # which otherwise walk all of it (≈ 250 000 objects) and paused a request for 100–150 ms
    gc.collect()
    gc.freeze()
    thresholds = gc.get_threshold()
    gc.set_threshold(*GC_THRESHOLDS)
    for t in threads:
        t.start()
    try:
        yield
    finally:
        gc.set_threshold(*thresholds)
        gc.unfreeze()  # another app in this process (tests) must not keep this one's cycles
        stop.set()
        for t in threads:
            t.join(timeout=10)
        if app.state.mqtt is not None:
            app.state.mqtt.stop()
        app.state.probe_threads.shutdown(wait=False, cancel_futures=True)
        db.dispose()


def mqtt_bridge(db: Database, settings: Settings, backfill: Backfill) -> MqttBridge | None:
    """With ``--mqtt URL``: the MQTT feed's bridge (not yet started); its setpoints are valid for
    as long as the HTTP pull's, and it takes rows within the same ``backfill`` horizon as
    ``POST /telemetry``."""
    if settings.mqtt_url is None:
        return None
    broker = settings.broker(settings.mqtt_username, settings.mqtt_password)
    valid_for = settings.stale_periods * timedelta(minutes=settings.sampling_min)
    return MqttBridge(
        db, broker, client_id=settings.mqtt_client_id, valid_for=valid_for, backfill=backfill
    )


def broker_clients(settings: Settings) -> BrokerClients | None:
    """With ``--mqtt-dynsec``: the gateway tokens' broker clients, kept as the plugin's admin."""
    if not settings.mqtt_dynsec:
        return None
    admin = settings.broker(settings.mqtt_dynsec_username, settings.mqtt_dynsec_password)
    return BrokerClients(admin)


def _error(status: int):
    def handler(_request: Request, exc: Exception) -> JSONResponse:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return JSONResponse({"detail": message}, status_code=status)

    return handler


def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 with pydantic's errors, as FastAPI gives them; an error that cannot be sent as it is
    (its input a NaN or an infinity, or text with a lone surrogate) loses the input and its
    context, so the answer to a malformed request never fails itself."""
    errors = []
    for error in jsonable_encoder(exc.errors()):
        try:
            json.dumps(error, allow_nan=False, ensure_ascii=False).encode("utf-8")
        except ValueError:  # UnicodeEncodeError included
            error.pop("input", None)
            error.pop("ctx", None)
        errors.append(error)
    return JSONResponse({"detail": errors}, status_code=422)


def create_app(settings: Settings | None = None) -> FastAPI:
    """The application for ``settings`` (default: from the environment)."""
    settings = settings or Settings()
    app = FastAPI(
        title="trainclimate",
        version=__version__,
        summary="Data-driven predictive HVAC energy management for SBB Regio-Dosto coaches",
        description=(
            "Scheduled DDPC per coach, telemetry and setpoints in SQL, operator overrides, and "
            "activated-vs-deactivated comparisons. Authenticate with `Authorization: Bearer "
            "<token>` (`trainclimate token create`); reads need viewer, writes operator, user and "
            "model management admin."
        ),
        lifespan=lifespan,
        docs_url=None,  # served by docpages, from the service itself
        redoc_url=None,
    )
    app.state.settings = settings
    app.include_router(api.router)
    docpages.install(app)
    spec.install(app)
    for exc, status in api.ERROR_STATUS.items():
        app.add_exception_handler(exc, _error(status))
    # a database that does not answer, or whose connections are all in use: 503 with
    # Retry-After; a transaction that lost a race (deadlock, serialization) is run again first
    app.add_exception_handler(OperationalError, database_error(DATABASE_RETRY_AFTER_S))
    app.add_exception_handler(PoolTimeoutError, database_error(OVERLOAD_RETRY_AFTER_S))
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(DynsecError, _error(503))  # a gateway token's broker client
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "PUT", "DELETE"],
            allow_headers=["Authorization", "Content-Type"],
        )
    # outermost last: with trusted proxies the client they name (uvicorn's proxy headers), the
    # headers on every answer (429, 422, 413 and 503 included), then the throttle, the refusal
    # of a NUL in the path or query, the body limit, the admission and the rerun of requests
    # that lost a race
    app.state.read_cache = ReadCache(settings.read_cache_size)
    app.state.backfill = Backfill(
        timedelta(days=settings.backfill_horizon_days), timedelta(minutes=settings.max_ahead_min)
    )
    # the readiness probe's own threads: it never waits for the requests' worker threads
    app.state.probe_threads = ThreadPoolExecutor(2, thread_name_prefix="ready-probe")
    app.state.admission = Slots(settings.worker_threads, settings.overload_wait_s)
    app.add_middleware(RetryConflicts)
    app.add_middleware(Admission, slots=app.state.admission)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(RefuseNul)
    app.state.auth_failures = FailureCounter(
        settings.auth_failures_burst, settings.auth_failures_window_s
    )
    app.add_middleware(
        AuthFailureThrottle,
        counter=app.state.auth_failures,
        verify=lambda authorization: valid_authorization(app.state.db, authorization),
    )
    app.add_middleware(SecurityHeaders)
    # the dashboard's files kept by the browser (versioned) or revalidated; gzip on every answer
    # of 1 kB or more (Plotly.js, the scripts, the API's JSON and CSV) to a client that takes it,
    # at level 4: a 30-day fleet summary (690 kB) in 4 ms to 106 kB, where level 9 (Starlette's
    # default) took 13 ms for 97 kB (measured)
    app.add_middleware(dashboard_files.DashboardCaching)
    app.add_middleware(GZipMiddleware, minimum_size=1000, compresslevel=4)
    if settings.forwarded_allow_ips:
        app.add_middleware(ProxyHeadersMiddleware, trusted_hosts=settings.forwarded_allow_ips)
    # outermost: the request id on every answer and in the log lines, the metrics of every answer
    app.state.metrics = metrics.Metrics(settings.replica_name)
    refresher = metrics.Refresher(settings.metrics_refresh_s)
    app.state.metrics_refresher = metrics.install(app.state.metrics, app.state, refresher).refresher
    app.add_middleware(Observe, metrics=app.state.metrics)
    if (settings.frontend_dir / "index.html").exists():
        # Plotly.js from npm's basic bundle or the plotly package: no CDN and no build
        app.add_api_route(
            "/vendor/plotly.min.js",
            lambda: FileResponse(
                dashboard_files.plotly_js(settings.frontend_dir), media_type="text/javascript"
            ),
            include_in_schema=False,
        )
        # index.html with versioned URLs for its script, style and Plotly.js
        for path in ("/", "/index.html"):
            app.add_api_route(
                path,
                lambda: dashboard_files.index_response(settings.frontend_dir),
                include_in_schema=False,
            )
        app.mount("/", StaticFiles(directory=settings.frontend_dir, html=True), name="frontend")
    return app
