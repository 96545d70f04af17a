"""An onboard gateway emulator (``trainclimate gateway``): a separate process that speaks only the
live feed's HTTP protocol.

It simulates its coaches (one train: the coaches share place, weather and operation, like a pair)
with the thermal simulator, on a clock ``speedup`` times faster than real time, and every minute
of that clock it

- POSTs the minute's telemetry of each coach to ``/api/v1/telemetry`` — rows that could not be
  sent stay in a buffer and go with the next batch (the server skips rows it already has), so a
  lost connection loses no data;
- GETs each coach's setpoint from ``/api/v1/coaches/{id}/setpoint`` (a pull) and applies it while
  it is valid; without one — none issued, expired, or the server unreachable — the HVAC falls back
  to its own T_rule, as a real coach does.

At start it registers its coaches (``POST /api/v1/coaches``; an existing coach is left as it is);
while the server cannot be reached it runs on, keeps its telemetry and tries again every minute;
at the end it keeps trying for a minute more to send what is left. A refusal (a bad token, a
coach of another train, a coach its gateway token is not scoped to) stops it with the server's
answer. Those three calls are all it makes: a ``gateway`` token scoped to its coaches
(``trainclimate token create --role gateway --coaches …``) is all it needs.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import httpx
import numpy as np
import pandas as pd

from trainclimate.service.store.telemetry import rows_from_simulation, to_wire
from trainclimate.sim import scenarios
from trainclimate.sim.rule import MODE_REGULAR
from trainclimate.sim.setpoint import apply_setpoint
from trainclimate.sim.simulator import Environment, FleetSimulator

log = logging.getLogger(__name__)


@dataclass
class GatewayStats:
    """What the gateway did (printed as JSON when it stops)."""

    minutes: int = 0
    rows_sent: int = 0
    failed_posts: int = 0
    rows_unsent: int = 0
    setpoints_applied: int = 0
    fallbacks_to_rule: int = 0
    sources: dict[str, int] = field(default_factory=dict)


class Gateway:
    """The emulator for ``coach_ids`` of train ``train_id`` (see the module docstring)."""

    def __init__(
        self,
        server: str,
        token: str,
        coach_ids: list[str],
        *,
        train_id: str,
        active: list[str],
        scenario: str = "parked-heating-nov",
        speedup: float = 60.0,
        hours: float | None = None,
        timeout_s: float = 2.0,
    ):
        self.client = httpx.Client(
            base_url=server.rstrip("/") + "/api/v1",
            headers={"Authorization": f"Bearer {token}"},
            timeout=timeout_s,
        )
        self.ids = list(coach_ids)
        self.train_id = train_id
        self.active = set(active)
        self.speedup = float(speedup)
        sc = scenarios.get(scenario)
        env1, params = scenarios.build(sc, n_coaches=1, hours=hours)
        env = Environment.side_by_side([env1] * len(self.ids))  # one train: shared conditions
        self.sim = FleetSimulator([params[0]] * len(self.ids), env, seed=sc.seed)
        self.t_ref = np.full(len(self.ids), np.nan)
        self.valid_until: list[pd.Timestamp | None] = [None] * len(self.ids)
        self.buffer: dict[str, list[dict]] = {cid: [] for cid in self.ids}
        self.registered = False
        self.stats = GatewayStats()

    def register(self) -> bool:
        """Register the coaches; False while the server is unreachable or unavailable (5xx).
        A refusal (4xx) raises :class:`httpx.HTTPStatusError`."""
        try:
            for cid in self.ids:
                body = {"id": cid, "train_id": self.train_id, "ddpc_active": cid in self.active}
                self.client.post("/coaches", json=body).raise_for_status()
        except httpx.HTTPStatusError as exc:
            if exc.response.status_code < 500:
                raise
            log.warning("coaches not registered (server unavailable), retrying: %s", exc)
            return False
        except httpx.TransportError as exc:
            log.warning("coaches not registered (server unreachable), retrying: %s", exc)
            return False
        self.registered = True
        return True

    def _policy(self, k: int, sim: FleetSimulator) -> np.ndarray:
        now = sim.env.time[k]
        valid = np.array([v is not None and now < v for v in self.valid_until])
        return apply_setpoint(self.t_ref, sim.t_rule(k), valid & (sim.env.mode[k] == MODE_REGULAR))

    def _send(self) -> None:
        for cid, rows in self.buffer.items():
            if not rows:
                continue
            body = {"coach_id": cid, "rows": [to_wire(r) for r in rows]}
            try:
                self.client.post("/telemetry", json=body).raise_for_status()
            except httpx.HTTPError as exc:
                self.stats.failed_posts += 1
                log.warning("telemetry for %s not sent (kept for the next batch): %s", cid, exc)
                continue
            self.stats.rows_sent += len(rows)
            self.buffer[cid] = []

    def _pull(self) -> None:
        for c, cid in enumerate(self.ids):
            try:
                reply = self.client.get(f"/coaches/{cid}/setpoint")
                reply.raise_for_status()
                sp = reply.json()
            except httpx.HTTPError as exc:
                log.warning("no setpoint for %s (keeping the last while valid): %s", cid, exc)
                continue
            if sp["t_ref_c"] is None or sp["valid_until"] is None:
                self.valid_until[c] = None
                continue
            self.t_ref[c] = sp["t_ref_c"]
            self.valid_until[c] = pd.Timestamp(sp["valid_until"])
            self.stats.sources[sp["source"]] = self.stats.sources.get(sp["source"], 0) + 1

    def minute(self) -> None:
        """One minute of the coaches' life: simulate, report, pull the setpoints."""
        k0 = self.sim.k
        steps = round(60.0 / self.sim.dt_s)
        self.sim.run(self._policy, steps=steps)
        now = self.sim.env.time[self.sim.k - 1] + pd.Timedelta(seconds=self.sim.dt_s)
        applied = [v is not None and now <= v for v in self.valid_until]
        self.stats.setpoints_applied += sum(applied)
        self.stats.fallbacks_to_rule += len(applied) - sum(applied)
        for cid, rows in rows_from_simulation(self.sim, k0, self.sim.k, self.ids).items():
            self.buffer[cid].extend(rows)
        if self.registered or self.register():
            self._send()
            self._pull()
        self.stats.minutes += 1

    def run(self) -> GatewayStats:
        """Run to the end of the scenario's span, ``speedup`` times faster than real time."""
        self.register()
        wall0 = time.monotonic()
        while self.sim.k + round(60.0 / self.sim.dt_s) <= self.sim.n_steps:
            self.minute()
            ahead = self.stats.minutes * 60.0 / self.speedup - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        self._flush()
        return self.stats

    def _flush(self, patience_s: float = 60.0) -> None:
        """At the end: send what is still kept, retrying every second for ``patience_s`` s (wall
        time) while the server is unreachable; what is left then is counted in ``rows_unsent``."""
        deadline = time.monotonic() + patience_s
        while any(self.buffer.values()) and time.monotonic() < deadline:
            if self.registered or self.register():
                self._send()
            if any(self.buffer.values()):
                time.sleep(1.0)
        self.stats.rows_unsent = sum(len(rows) for rows in self.buffer.values())
        if self.stats.rows_unsent:
            log.error("%d telemetry rows could not be sent", self.stats.rows_unsent)
