"""The gateway emulator backs off while the server is unreachable: after each failed attempt it
waits twice as long (1 s, 2 s, 4 s … at most 60 s of wall time) before the next, keeping its
telemetry meanwhile, and tries at once again after a success."""

from __future__ import annotations

import itertools

from service_processes import free_port
from trainclimate.service.adapters import gateway as gateway_module
from trainclimate.service.adapters.gateway import BACKOFF_S, Gateway


def test_the_gateway_backs_off_exponentially_up_to_a_cap(monkeypatch):
    now = [1000.0]
    monkeypatch.setattr(gateway_module.time, "monotonic", lambda: now[0])
    url = f"http://127.0.0.1:{free_port()}"  # nothing listens there
    gw = Gateway(url, "tc_x", ["124-A", "124-B"], train_id="124", active=["124-A"], hours=7.0)
    attempts = []
    real_register = gw.register

    def register():
        attempts.append(now[0])
        return real_register()

    monkeypatch.setattr(gw, "register", register)
    for _ in range(400):  # 400 minutes of its clock, one wall second each
        gw.minute()
        now[0] += 1.0
    waits = [b - a for a, b in itertools.pairwise(attempts)]
    assert waits[:7] == [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 60.0]
    assert set(waits[7:]) == {BACKOFF_S[1]}
    assert sum(len(rows) for rows in gw.buffer.values()) == 2 * 400  # every row kept
    # after a success the next failure waits the shortest again
    gw._reachable()
    gw._unreachable()
    assert gw._retry_at == now[0] + BACKOFF_S[0]
