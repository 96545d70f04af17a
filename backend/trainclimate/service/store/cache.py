"""An in-process cache of the expensive reads: each coach's view (the fleet list is made of them),
the pair comparisons, and the fleet summary's sums per train.

An answer is kept under its request's key (a coach; a train, range and window length) together
with the state of everything it is computed from, read from the database at the start of each
request in a few index probes (:func:`~trainclimate.service.store.queries.coach_states`,
:func:`~trainclimate.service.store.queries.comparison_state`). It is served only while that state
is unchanged. Telemetry and setpoints are only ever inserted, clocks only advance and an override
is only ever cancelled once, so a new telemetry row, setpoint or override, or a cancellation,
changes the state, and the next request computes its answer afresh: a served answer is the one a
fresh computation gives at the time of the request.

The cache is bounded (least recently used keys go first) and shared by the server's threads.
Requests that miss on the same key and state at the same time compute the answer once: the first
computes, the others wait for its answer (or its error).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from typing import Any


class ReadCache:
    """At most ``size`` answers, one per key, the least recently used dropped first (``size`` 0:
    nothing is kept, every request computes); thread-safe. ``misses`` counts the answers
    computed, ``hits`` those served without computing (kept, or computed by another request at
    the same time). A served answer is shared: callers must not change it."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.hits = 0
        self.misses = 0
        self._answers: OrderedDict[Hashable, tuple[Hashable, Any]] = OrderedDict()
        self._computing: dict[tuple[Hashable, Hashable], Future] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._answers)

    def get(self, key: Hashable, state: Hashable, compute: Callable[[], Any]) -> Any:
        """The answer kept under ``key`` if it was computed in ``state``; else ``compute()``'s,
        kept under ``key`` with ``state`` (an error is raised, not kept), or the answer of
        another thread computing the same key and state."""
        if self.size == 0:
            return compute()
        with self._lock:
            found, answer = self._kept(key, state)
            if found:
                return answer
            pending = self._computing.get((key, state))
            if pending is None:
                self.misses += 1
                mine: Future[Any] = Future()
                self._computing[key, state] = mine
            else:
                self.hits += 1
        if pending is not None:
            return pending.result()
        try:
            answer = compute()
        except BaseException as exc:
            with self._lock:
                del self._computing[key, state]
            mine.set_exception(exc)
            raise
        with self._lock:
            del self._computing[key, state]
            self._keep(key, state, answer)
        mine.set_result(answer)
        return answer

    def lookup(self, key: Hashable, state: Hashable) -> Any | None:
        """The answer kept under ``key`` if it was computed in ``state``, else None (counted as
        a hit or a miss). For callers that compute many answers at once and :meth:`put` them."""
        with self._lock:
            found, answer = self._kept(key, state)
            if not found:
                self.misses += 1
            return answer

    def peek(self, key: Hashable) -> tuple[Hashable, Any] | None:
        """(state, answer) kept under ``key`` whatever its state, else None — for answers whose
        state the caller can only judge from the answer itself (which range it covers); not
        counted, and not made the most recently used: what the caller makes of it is."""
        with self._lock:
            return self._answers.get(key)

    def holds(self, key: Hashable, state: Hashable) -> bool:
        """Whether an answer computed in ``state`` is kept under ``key``; as :meth:`peek`, not
        counted and not made the most recently used (for callers that read together what the
        answers to compute need)."""
        with self._lock:
            kept = self._answers.get(key)
            return kept is not None and kept[0] == state

    def put(self, key: Hashable, state: Hashable, answer: Any) -> None:
        """Keep ``answer`` under ``key``, computed in ``state`` (nothing with ``size`` 0)."""
        if self.size == 0:
            return
        with self._lock:
            self._keep(key, state, answer)

    def _kept(self, key: Hashable, state: Hashable) -> tuple[bool, Any]:
        """(True, the answer) if one computed in ``state`` is kept under ``key`` (a hit, now the
        most recently used), else (False, None). Call with the lock held."""
        kept = self._answers.get(key)
        if kept is None or kept[0] != state:
            return False, None
        self._answers.move_to_end(key)
        self.hits += 1
        return True, kept[1]

    def _keep(self, key: Hashable, state: Hashable, answer: Any) -> None:
        """Keep ``answer`` under ``key``, dropping the least recently used beyond ``size``. Call
        with the lock held."""
        self._answers[key] = (state, answer)
        self._answers.move_to_end(key)
        if len(self._answers) > self.size:
            self._answers.popitem(last=False)
