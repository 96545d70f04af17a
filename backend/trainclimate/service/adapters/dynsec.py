"""Each gateway token's own broker client, kept by Mosquitto's dynamic security plugin
(``serve --mqtt --mqtt-dynsec``): the broker's users then follow the tokens.

- **Created with the token.** ``POST /api/v1/tokens`` with a gateway token creates the broker
  client ``tc-gateway-{token id}`` (:func:`username`), whose password is the token itself, with a
  role of its own that lets it publish its coaches' telemetry and subscribe to their setpoints and
  confirmations, nothing else. The answer names the user (``mqtt_username``).
- **Deleted at revocation.** ``DELETE /api/v1/tokens/{id}`` deletes the client and its role; the
  plugin disconnects the gateway at once and refuses its next connection.
- **Swept.** Every :data:`SWEEP_S` seconds the service deletes every ``tc-gateway-…`` client
  whose token is revoked, expired or unknown: a revocation while the broker was unreachable, a
  token that expired, a client left by a creation that was rolled back.

The service speaks to the plugin as its admin (``$CONTROL/dynamic-security/v1``; the credentials
from ``$TRAINCLIMATE_MQTT_DYNSEC_USERNAME`` and ``$TRAINCLIMATE_MQTT_DYNSEC_PASSWORD``), one
short connection per operation. A token made by ``trainclimate token create`` writes the database
only: it gets no broker client.
"""

from __future__ import annotations

import json
import logging
import re
import threading
import uuid
from collections.abc import Iterable

from sqlalchemy import or_, select
from sqlalchemy.orm import Session

from trainclimate.service.adapters.mqtt import Broker
from trainclimate.service.store.db import Database
from trainclimate.service.store.models import ApiToken, utcnow
from trainclimate.service.store.tokens import hash_token

log = logging.getLogger(__name__)

#: The plugin's command topic (its answers come on ``…/response``).
CONTROL = "$CONTROL/dynamic-security/v1"
#: How often stale gateway clients are swept. [s]
SWEEP_S = 60.0
#: How long to wait for the plugin's answer. [s]
TIMEOUT_S = 5.0
_USERNAME = re.compile(r"^tc-gateway-(\d+)$")
#: What deleting something that is not there answers (nothing to do).
_ABSENT = {"Client not found", "Role not found"}


class DynsecError(RuntimeError):
    """The plugin did not do what was asked (the message says why)."""


def username(token_id: int) -> str:
    """The broker user (and role) of gateway token ``token_id``."""
    return f"tc-gateway-{token_id}"


class BrokerClients:
    """The gateway tokens' broker clients on ``broker`` (its credentials: the plugin's admin)."""

    def __init__(self, broker: Broker, timeout_s: float = TIMEOUT_S):
        self.broker = broker
        self.timeout_s = timeout_s

    def add(self, session: Session, token: str, coaches: list[str]) -> str:
        """Create the broker client of the gateway ``token`` just made in ``session`` (a client
        of the same name is replaced); returns its user name. :class:`DynsecError` if the plugin
        does not create it."""
        session.flush()
        made = select(ApiToken.id).where(ApiToken.token_hash == hash_token(token))
        name = username(session.scalar(made))
        client = {"command": "createClient", "username": name, "password": token}
        try:
            self._run(
                *_deletions([name]),
                {"command": "createRole", "rolename": name, "acls": self.acls(coaches)},
                client | {"roles": [{"rolename": name}]},
            )
        except DynsecError as exc:
            raise DynsecError(f"the broker did not create the gateway's client: {exc}") from None
        return name

    def acls(self, coaches: list[str]) -> list[dict]:
        """A gateway's ACLs: publish its coaches' telemetry, subscribe to their setpoints and
        confirmations (everything else the plugin denies by default)."""
        return [
            {"acltype": acltype, "topic": self.broker.topic(coach, kind), "allow": True}
            for coach in coaches
            for acltype, kind in (
                ("publishClientSend", "telemetry"),
                ("subscribeLiteral", "setpoint"),
                ("subscribeLiteral", "stored"),
            )
        ]

    def remove(self, token_id: int) -> None:
        """Delete the broker client of gateway token ``token_id`` and its role (the plugin
        disconnects it); if the plugin cannot be reached, say so in the log: the next sweep
        deletes it."""
        try:
            self._run(*_deletions([username(token_id)]))
        except DynsecError as exc:
            log.warning("MQTT: broker client %s left to the sweep: %s", username(token_id), exc)

    def sweep(self, db: Database) -> list[str]:
        """Delete the gateway clients whose token is revoked, expired or unknown; returns
        their names."""
        [listed] = self._run({"command": "listClients", "verbose": False, "count": -1})
        names = {int(m[1]): m[0] for m in map(_USERNAME.match, listed["data"]["clients"]) if m}
        with db.transaction() as session:
            valid = valid_tokens(session, names)
        stale = sorted(name for token_id, name in names.items() if token_id not in valid)
        if stale:
            self._run(*_deletions(stale))
            log.info("MQTT: deleted the broker clients of revoked or expired tokens: %s", stale)
        return stale

    def run(self, db: Database, stop: threading.Event) -> None:
        """Sweep every :data:`SWEEP_S` seconds until ``stop`` is set (failures are logged)."""
        while not stop.is_set():
            try:
                self.sweep(db)
            except Exception as exc:  # the broker or the database away: the next sweep retries
                log.warning("MQTT: broker clients not swept: %s", exc)
            stop.wait(SWEEP_S)

    def _run(self, *commands: dict) -> list[dict]:
        """Send ``commands`` to the plugin in one message and return its answers, in order;
        :class:`DynsecError` on an error (other than deleting what is absent) or no answer."""
        tag = uuid.uuid4().hex
        tagged = [{**c, "correlationData": f"{tag}-{i}"} for i, c in enumerate(commands)]
        answers = self._exchange(json.dumps({"commands": tagged}), tag)
        for answer in answers:
            if answer.get("error") and answer["error"] not in _ABSENT:
                raise DynsecError(f"{answer['command']}: {answer['error']}")
        return answers

    def _exchange(self, payload: str, tag: str) -> list[dict]:
        """Publish ``payload`` on :data:`CONTROL` and wait for the answers tagged ``tag``."""
        answers: list[dict] = []
        refused: list[str] = []
        subscribed, answered = threading.Event(), threading.Event()

        def on_connect(_c, _u, _f, reason, _p) -> None:
            if reason.is_failure:
                refused.append(str(reason))
                subscribed.set()

        def on_message(_c, _u, msg) -> None:
            got = json.loads(msg.payload).get("responses", [])
            if got and str(got[0].get("correlationData", "")).startswith(f"{tag}-"):
                answers.extend(got)
                answered.set()

        client = self.broker.client(f"trainclimate-dynsec-{tag[:12]}")
        client.on_connect = on_connect
        client.on_subscribe = lambda *_: subscribed.set()
        client.on_message = on_message
        try:
            client.connect(self.broker.host, self.broker.port, keepalive=30)
        except OSError as exc:
            raise DynsecError(f"no broker at {self.broker.address}: {exc}") from None
        client.loop_start()
        try:
            client.subscribe(f"{CONTROL}/response", qos=1)
            if not subscribed.wait(self.timeout_s) or refused:
                why = refused[0] if refused else "no answer"
                raise DynsecError(f"{self.broker.address} refused the admin: {why}")
            client.publish(CONTROL, payload, qos=1)
            if not answered.wait(self.timeout_s):
                why = f"did not answer in {self.timeout_s:g} s"
                raise DynsecError(f"the dynamic security plugin {why}")
        finally:
            client.disconnect()
            client.loop_stop()
        return answers


def _deletions(names: Iterable[str]) -> list[dict]:
    """Delete the clients ``names`` and their roles (one each, of the same name)."""
    out: list[dict] = []
    for name in names:
        out.append({"command": "deleteClient", "username": name})
        out.append({"command": "deleteRole", "rolename": name})
    return out


def valid_tokens(session: Session, token_ids: Iterable[int]) -> set[int]:
    """Which of ``token_ids`` are tokens neither revoked nor expired."""
    now = utcnow()
    query = select(ApiToken.id).where(
        ApiToken.id.in_(list(token_ids)),
        ApiToken.revoked_at.is_(None),
        or_(ApiToken.expires_at.is_(None), ApiToken.expires_at > now),
    )
    return set(session.scalars(query))
