"""The cache's lock: a second process wanting a cached artifact waits for the first's build
instead of building it alongside (two builds in one directory corrupted a dataset once)."""

from __future__ import annotations

import multiprocessing
import time

from trainclimate.data import cache


def _hold(target, seconds, started):
    with cache.exclusive(target):
        started.set()
        time.sleep(seconds)


def test_a_second_process_waits_for_the_first_s_build(tmp_path):
    target = tmp_path / "fleet-x"
    ctx = multiprocessing.get_context("spawn")
    started = ctx.Event()
    first = ctx.Process(target=_hold, args=(target, 1.0, started))
    first.start()
    try:
        assert started.wait(30)
        t0 = time.monotonic()
        with cache.exclusive(target):
            waited = time.monotonic() - t0
        assert waited > 0.5  # it waited for the first build's end
    finally:
        first.join(30)
    assert first.exitcode == 0
    # free again: taken at once
    t0 = time.monotonic()
    with cache.exclusive(target):
        assert time.monotonic() - t0 < 0.5
