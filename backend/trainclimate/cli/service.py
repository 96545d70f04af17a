"""``serve``, ``token create`` and ``gateway``: the service and its live feed."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from trainclimate.cli.common import (
    UsageError,
    add_command,
    add_group,
    db_url,
    emit,
    migrated_database,
    out_file,
)

if TYPE_CHECKING:
    from trainclimate.service.settings import Settings


def cmd_serve(args: argparse.Namespace) -> None:
    """``serve``: migrate, then run the API, the dashboard and the loops until Ctrl-C."""
    import uvicorn
    from sqlalchemy.engine import make_url

    from trainclimate.service import logs
    from trainclimate.service.app import create_app

    settings = serve_settings(args)
    if args.coach_params is not None:
        if args.fleet != "demo":
            raise UsageError("--coach-params sets the demo fleet's coaches: give --fleet demo")
        from trainclimate.sim.params import load_params
        from trainclimate.twin import validity

        # a bad file is a one-line error before anything starts
        load_params(args.coach_params)
        record = validity.record_of_file(args.coach_params)
        validity.validated_range(record, f"coach parameter file {args.coach_params}")
        validity.savings_warning(record, f"coach parameter file {args.coach_params}")
    _check_dynsec(args, settings)
    url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '::') else args.host}:{args.port}/"
    migrated_database(settings.database_url)  # else one line, not a traceback
    lines = [f"trainclimate: serving on {url} (database {settings.database_url.split('://')[0]})"]
    broker = None
    if settings.mqtt_url is not None:
        broker = settings.broker(settings.mqtt_username, settings.mqtt_password)
        lines.append(f"trainclimate: MQTT feed on {broker.address}, topics {broker.prefix}/…")
    token = None
    if args.new_token:
        token = _create_token(settings.database_url, args.new_token, f"demo-{args.new_token}")
    app = create_app(settings)
    # text for a terminal, or one JSON object a line (uvicorn's lines too: it configures nothing)
    log_config = logs.configure(args.log_format, args.log_level, settings.replica_name)
    # X-Forwarded-For only from the trusted proxies, which the app itself handles (create_app):
    # uvicorn's own handling, on by default, would trust 127.0.0.1
    config = uvicorn.Config(
        app,
        host=args.host,
        port=args.port,
        log_level=args.log_level,
        log_config=log_config,
        proxy_headers=False,
    )
    server = uvicorn.Server(config)

    def announce() -> dict:
        """What ``serve`` prints once it accepts connections."""
        status = app.state.preparation.status
        return {
            "url": url,
            # the one URL that signs in (the token in the fragment reaches no server log)
            "dashboard": f"{url}#token={token['token']}" if token else url,
            "token": token["token"] if token else None,
            "role": args.new_token,
            "database": make_url(settings.database_url).render_as_string(hide_password=True),
            "replica": settings.replica_name,
            "model": {"state": status.state, "stage": status.stage, "detail": status.detail},
            "mqtt": broker.address if broker is not None else None,
        }

    threading.Thread(
        target=_announce, args=(server, args, lines, announce), name="announce", daemon=True
    ).start()
    server.run()


#: The ``serve`` options that set a setting (:class:`~trainclimate.service.settings.Settings`):
#: field → option (``--mqtt-password-file``: the password read from that file).
SERVE_OPTIONS = {
    "database_url": "--db",
    "fleet": "--fleet",
    "speedup": "--speedup",
    "demo_coach_params": "--coach-params",
    "predictor_path": "--predictor",
    "backfill_horizon_days": "--backfill-horizon-days",
    "max_ahead_min": "--max-ahead-min",
    "guard_days": "--guard-days",
    "forwarded_allow_ips": "--forwarded-allow-ips",
    "replica_name": "--replica-name",
    "mqtt_url": "--mqtt",
    "mqtt_username": "--mqtt-username",
    "mqtt_password": "--mqtt-password-file",
    "mqtt_ca_file": "--mqtt-ca",
    "mqtt_prefix": "--mqtt-prefix",
    "mqtt_client_id": "--mqtt-client-id",
    "mqtt_dynsec": "--mqtt-dynsec",
}


def serve_settings(args: argparse.Namespace) -> Settings:
    """The settings of ``serve``: its options over the environment (``TRAINCLIMATE_*``) over the
    defaults. ``--db`` (else ``$TRAINCLIMATE_DATABASE_URL``), ``--fleet``, ``--speedup``,
    ``--coach-params`` and ``--predictor`` always set theirs; the other options only when given,
    and the broker's options only with ``--mqtt``. A value the settings refuse is a
    :class:`UsageError` naming its option, or its environment variable."""
    from pydantic import ValidationError

    from trainclimate.service.settings import Settings, env_var, problem

    given: dict[str, Any] = {
        "database_url": db_url(args),
        "fleet": args.fleet,
        "speedup": args.speedup,
        "demo_coach_params": args.coach_params,
        "predictor_path": args.predictor,
    }
    for name in (
        "backfill_horizon_days",
        "max_ahead_min",
        "guard_days",
        "forwarded_allow_ips",
        "replica_name",
    ):
        if getattr(args, name) is not None:
            given[name] = getattr(args, name)
    if args.mqtt is not None:
        given |= {
            "mqtt_url": args.mqtt,
            "mqtt_username": args.mqtt_username,
            "mqtt_ca_file": args.mqtt_ca,
            "mqtt_prefix": args.mqtt_prefix,
            "mqtt_client_id": args.mqtt_client_id,
            "mqtt_dynsec": args.mqtt_dynsec,
        }
        if args.mqtt_password_file:  # else $TRAINCLIMATE_MQTT_PASSWORD, else the URL's
            given["mqtt_password"] = read_password(args.mqtt_password_file)
    try:
        return Settings(**given)
    except ValidationError as exc:
        error = exc.errors()[0]
        if not error["loc"]:
            raise UsageError(problem(error)) from None
        name = str(error["loc"][0])
        where = SERVE_OPTIONS[name] if name in given and name in SERVE_OPTIONS else env_var(name)
        raise UsageError(f"{where}: {problem(error)}") from None


def setting_help(name: str, *, env: bool = True, more: str = "") -> str:
    """The help of the ``serve`` option that sets setting ``name``: its description, then its
    default where it is a fixed value, its environment variable with ``env`` (where the option
    leaves it in force) and ``more``, in parentheses (the description's own, if it ends with
    them); ``%`` escaped for argparse."""
    from pydantic_core import PydanticUndefined

    from trainclimate.service.settings import Settings, env_var

    field = Settings.model_fields[name]
    notes = []
    if field.default not in (None, PydanticUndefined) and not isinstance(field.default, bool):
        value = field.default
        notes.append(f"default {value:g}" if isinstance(value, float) else f"default {value}")
    if env:
        notes.append(f"${env_var(name)}")
    if more:
        notes.append(more)
    text = str(field.description)
    if notes:  # in the description's closing parenthesis, if it has one
        text = f"{text[:-1]}; " if text.endswith(")") else f"{text} ("
        text += "; ".join(notes) + ")"
    return text.replace("%", "%%")


def _check_dynsec(args: argparse.Namespace, settings: Settings) -> None:
    """``--mqtt-dynsec`` needs ``--mqtt`` and the plugin admin's credentials."""
    if not args.mqtt_dynsec:
        return
    if args.mqtt is None:
        raise UsageError("--mqtt-dynsec needs --mqtt: the broker whose clients it keeps")
    if not (settings.mqtt_dynsec_username and settings.mqtt_dynsec_password):
        raise UsageError(
            "--mqtt-dynsec needs the dynamic security plugin's admin: set"
            " TRAINCLIMATE_MQTT_DYNSEC_USERNAME and TRAINCLIMATE_MQTT_DYNSEC_PASSWORD"
        )


def _announce(server, args: argparse.Namespace, stderr_lines: list[str], what) -> None:
    """Once the server accepts connections: with ``--json`` one JSON object on stdout (``what()``:
    URL, token, database, replica, model status, MQTT broker), else the log lines on stderr and
    the dashboard's URL and token on stdout."""
    while not server.started:
        if server.should_exit:
            return
        time.sleep(0.05)
    data = what()
    if args.json:
        print(json.dumps(data), flush=True)
        return
    if args.log_format == "json":  # the log stream stays one JSON object a line
        for line in stderr_lines:
            logging.getLogger("trainclimate.serve").info(line.removeprefix("trainclimate: "))
    else:
        print("\n".join(stderr_lines), file=sys.stderr, flush=True)
    if data["token"]:
        print(f"dashboard: {data['dashboard']}\n{data['role']} token: {data['token']}", flush=True)


def _create_token(
    url: str,
    role: str,
    name: str | None,
    coaches: list[str] | None = None,
    expires_at: datetime | None = None,
) -> dict:
    """A new token in the migrated database ``url`` (a gateway's scoped to ``coaches``, valid
    until ``expires_at``): {token, name, role, coaches, expires_at}. An existing user's token
    has the user's role: another role is a :class:`UsageError`."""
    from trainclimate.service.store.db import Database
    from trainclimate.service.store.tokens import RoleConflictError, create_token

    db = Database(url)
    try:
        with db.transaction() as session:
            try:
                token, user = create_token(session, role, name, coaches, expires_at)
            except RoleConflictError as exc:
                raise UsageError(f"--name: {exc}") from None
            expiry = expires_at.isoformat() if expires_at else None
            return {
                "token": token,
                "name": user.name,
                "role": user.role,
                "coaches": coaches,
                "expires_at": expiry,
            }
    finally:
        db.dispose()


def cmd_token_create(args: argparse.Namespace) -> None:
    """``token create``: a new token for a new user or an existing one of the same role, shown
    once (or written to ``--out``); a gateway's is scoped to ``--coaches``."""
    from trainclimate.service.api.schemas.users import MIN_EXPIRES_DAYS
    from trainclimate.service.store.tokens import USER_NAME_MAX, check_scope

    coaches = None
    if args.coaches is not None:
        coaches = [c.strip() for c in args.coaches.split(",") if c.strip()]
    if args.role == "gateway" and args.coaches is None:
        raise UsageError("--role gateway needs --coaches: the coach ids it is for, comma-separated")
    if args.role != "gateway" and args.coaches is not None:
        raise UsageError(f"--coaches is for --role gateway only, not {args.role}")
    try:
        check_scope(args.role, coaches)
    except ValueError as exc:
        raise UsageError(f"--coaches: {exc}") from None
    if args.name is not None and not (
        0 < len(args.name) <= USER_NAME_MAX and args.name.isprintable()
    ):
        raise UsageError(f"--name must be 1 to {USER_NAME_MAX} printable characters")
    if args.expires is not None and not (
        np.isfinite(args.expires) and MIN_EXPIRES_DAYS <= args.expires <= 3650
    ):
        raise UsageError(
            f"--expires takes a number of days in [{MIN_EXPIRES_DAYS:.6f}, 3650] "
            "(a minute to ten years)"
        )
    url = migrated_database(db_url(args))
    expires_at = None
    if args.expires is not None:  # from now, once the database is ready
        expires_at = datetime.now(UTC) + timedelta(days=args.expires)
    try:
        data = _create_token(url, args.role, args.name, coaches, expires_at)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = out_file(args.out, "the token file")
    if out is not None:  # for another process to read (the compose demo's gateways): owner-only
        out.touch(mode=0o600)
        out.chmod(0o600)  # also when the file was there before, with another mode
        out.write_text(data["token"] + "\n")
        data = {**data, "token": None, "file": str(out)}
        emit(args, data, lambda d: f"token written to {d['file']}")
        return
    emit(args, data, lambda d: d["token"])


def read_password(file: str) -> str:
    """The password in ``file`` (``--mqtt-password-file``), stripped; unreadable: a
    :class:`UsageError`."""
    try:
        return Path(file).read_text().strip()
    except OSError as exc:
        raise UsageError(f"--mqtt-password-file: {exc.strerror}: {file}") from None


def mqtt_broker(args: argparse.Namespace):
    """The broker of ``--mqtt`` and its options (None without ``--mqtt``); the password from
    ``--mqtt-password-file``, else ``$TRAINCLIMATE_MQTT_PASSWORD``, else the URL."""
    from trainclimate.service.adapters.mqtt import Broker, BrokerError

    if args.mqtt is None:
        return None
    password = os.environ.get("TRAINCLIMATE_MQTT_PASSWORD")
    if args.mqtt_password_file:
        password = read_password(args.mqtt_password_file)
    try:
        return Broker.from_url(
            args.mqtt,
            username=args.mqtt_username,
            password=password,
            ca_file=args.mqtt_ca,
            prefix=args.mqtt_prefix,
        )
    except BrokerError as exc:
        raise UsageError(f"--mqtt: {exc}") from None


def add_mqtt_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--mqtt URL`` (``what``: its help) and the broker's options, their help the
    settings' (:func:`setting_help`)."""
    from trainclimate.service.adapters import MQTT_PREFIX

    p.add_argument("--mqtt", default=None, metavar="URL", help=what)
    p.add_argument("--mqtt-username", default=None, help=setting_help("mqtt_username", env=False))
    p.add_argument(
        "--mqtt-password-file",
        default=None,
        help="a file holding the broker password (or $TRAINCLIMATE_MQTT_PASSWORD)",
    )
    p.add_argument("--mqtt-ca", default=None, help=setting_help("mqtt_ca_file", env=False))
    p.add_argument(
        "--mqtt-prefix", default=MQTT_PREFIX, help=setting_help("mqtt_prefix", env=False)
    )


def cmd_gateway(args: argparse.Namespace) -> None:
    """``gateway``: an onboard gateway emulator feeding the service over HTTP or MQTT."""
    import httpx

    from trainclimate.service.adapters.gateway import Gateway
    from trainclimate.sim import scenarios

    scenarios.get(args.scenario)
    coaches = [c for c in args.coaches.split(",") if c]
    if not coaches:
        raise UsageError("--coaches needs at least one coach id")
    active = [c for c in (args.active or coaches[0]).split(",") if c]
    if not set(active) <= set(coaches):
        raise UsageError("--active must name coaches of --coaches")
    token = args.token or os.environ.get("TRAINCLIMATE_TOKEN")
    if args.token_file:
        try:
            token = Path(args.token_file).read_text().strip()
        except OSError as exc:
            raise UsageError(f"--token-file: {exc.strerror}: {args.token_file}") from None
    if not token:
        raise UsageError(
            "--token, --token-file or TRAINCLIMATE_TOKEN is required: a gateway token for the"
            " coaches (or an operator token)"
        )
    if args.quiet:
        logging.getLogger(Gateway.__module__).setLevel(logging.WARNING)
    gateway = Gateway(
        args.server,
        token,
        coaches,
        train_id=args.train or coaches[0].split("-")[0],
        active=active,
        scenario=args.scenario,
        speedup=args.speedup,
        hours=args.hours,
        mqtt=mqtt_broker(args),
    )
    try:
        stats = gateway.run()
    except httpx.HTTPStatusError as exc:  # a refusal: a bad token, a coach of another train
        reply = exc.response
        try:
            detail = reply.json()["detail"]
        except (ValueError, KeyError, TypeError):
            detail = reply.reason_phrase
        raise UsageError(f"the server refused the gateway: {reply.status_code} {detail}") from None
    emit(args, dataclasses.asdict(stats), lambda d: json.dumps(d))


def register(sub) -> None:
    """Add ``serve``, ``token create`` and ``gateway`` to ``sub``."""
    from trainclimate.service.settings import Settings

    p = add_command(sub, "serve", cmd_serve, "run the service (API, dashboard, control loop)")
    p.add_argument("--db", default=None, help=setting_help("database_url"))
    p.add_argument(
        "--fleet", choices=("demo",), default=None, help=setting_help("fleet", env=False)
    )
    p.add_argument(
        "--speedup",
        type=float,
        default=Settings.model_fields["speedup"].default,
        help=setting_help("speedup", env=False),
    )
    p.add_argument(
        "--coach-params", default=None, help=setting_help("demo_coach_params", env=False)
    )
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--predictor", default=None, help=setting_help("predictor_path", env=False))
    p.add_argument("--log-level", default="warning")
    p.add_argument(
        "--log-format",
        choices=("text", "json"),
        default="text",
        help="text for a terminal (default), or one JSON object a line for a log store (time, "
        "level, logger, message, replica, request_id, coach, tick)",
    )
    p.add_argument(
        "--new-token",
        choices=("viewer", "operator", "admin"),
        default=None,
        help="create a token with this role at start and print it with the dashboard's URL",
    )
    add_mqtt_options(p, setting_help("mqtt_url", env=False))
    p.add_argument(
        "--mqtt-client-id",
        default=Settings.model_fields["mqtt_client_id"].default,
        help=setting_help("mqtt_client_id", env=False),
    )
    p.add_argument(
        "--backfill-horizon-days",
        type=float,
        default=None,
        help=setting_help("backfill_horizon_days"),
    )
    p.add_argument("--max-ahead-min", type=float, default=None, help=setting_help("max_ahead_min"))
    p.add_argument("--guard-days", type=int, default=None, help=setting_help("guard_days"))
    p.add_argument(
        "--mqtt-dynsec",
        action="store_true",
        help=setting_help(
            "mqtt_dynsec",
            env=False,
            more="the plugin admin's credentials from $TRAINCLIMATE_MQTT_DYNSEC_USERNAME and "
            "$TRAINCLIMATE_MQTT_DYNSEC_PASSWORD",
        ),
    )
    p.add_argument(
        "--forwarded-allow-ips",
        default=None,
        metavar="IPS",
        help=setting_help("forwarded_allow_ips"),
    )
    p.add_argument("--replica-name", default=None, help=setting_help("replica_name"))

    tsub = add_group(sub, "token", "API tokens")
    p = add_command(tsub, "create", cmd_token_create, "create a token (shown once)")
    roles = ("metrics", "gateway", "viewer", "operator", "admin")
    p.add_argument("--role", required=True, choices=roles)
    p.add_argument(
        "--coaches",
        default=None,
        help="with --role gateway (required): the coach ids it is for, comma-separated",
    )
    p.add_argument("--name", default=None, help="user name (default: generated)")
    p.add_argument("--db", default=None, help="database URL")
    p.add_argument("--out", default=None, help="write the token to this file (mode 600)")
    p.add_argument(
        "--expires", type=float, default=None, help="days until it stops working (default never)"
    )

    p = add_command(
        sub,
        "gateway",
        cmd_gateway,
        "an onboard gateway emulator (HTTP or MQTT live feed)",
    )
    p.add_argument("--server", required=True, help="the service's URL, e.g. http://127.0.0.1:8000")
    p.add_argument("--coaches", required=True, help="coach ids, comma-separated (one train)")
    p.add_argument("--active", default=None, help="coaches with the layer on (default: the first)")
    p.add_argument("--train", default=None, help="train id (default: the first coach's prefix)")
    p.add_argument(
        "--token",
        default=None,
        help="a gateway token for the coaches, or an operator token (or $TRAINCLIMATE_TOKEN)",
    )
    p.add_argument("--token-file", default=None, help="a file holding the token")
    p.add_argument(
        "--scenario",
        default="parked-heating-nov",
        help="weather and operation (default: parked-heating-nov)",
    )
    p.add_argument(
        "--speedup",
        type=float,
        default=60.0,
        help="its clock × real time (default: 60, a simulated hour per wall minute)",
    )
    p.add_argument("--hours", type=float, default=None, help="how long (default: the scenario's)")
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no line per minute of its clock (sent, kept, T_ref); warnings still show",
    )
    add_mqtt_options(
        p, "send telemetry and take setpoints over this broker instead of HTTP, mqtt[s]://…"
    )
