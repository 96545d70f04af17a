"""``bench simulator``: simulated coach-days per second of the vectorised fleet simulator, against
a plain per-coach loop."""

from __future__ import annotations

import time

from trainclimate.bench.common import machine
from trainclimate.sim import scenarios
from trainclimate.sim.simulator import FleetSimulator

#: The vectorised fleet's target. [coach-days/s]
TARGET_COACH_DAYS_PER_S = 10.0


def run(coaches: int = 100, days: float = 1.0, loop_coaches: int = 5) -> dict:
    """Simulated coach-days per second for a vectorised fleet, against a per-coach loop.

    The fleet runs ``coaches`` half coaches of the ``winter-day`` scenario (in service, all
    blocks active) for ``days`` at the simulator's own 10 s step; the baseline simulates
    ``loop_coaches`` of the same coaches one at a time (one simulator per coach, the plain
    Python loop over coaches) and is scaled per coach-day. Environment construction (weather,
    routes) is not timed.

    Rates in coach-days/s (``coach_days_per_s``, ``loop_coach_days_per_s``), the fleet's run in
    s (``fleet_seconds``), the simulator's step ``dt_s`` in s.
    """
    scenario = scenarios.get("winter-day")
    env, params = scenarios.build(scenario, n_coaches=coaches, hours=24.0 * days)
    t0 = time.perf_counter()
    sim = FleetSimulator(params, env)
    sim.run()
    fleet_s = time.perf_counter() - t0

    n_loop = min(loop_coaches, coaches)
    t0 = time.perf_counter()
    for i in range(n_loop):
        single = FleetSimulator([params[i]], env.coaches([i]))
        single.run()
    loop_s = time.perf_counter() - t0

    fleet_rate = coaches * days / fleet_s
    loop_rate = n_loop * days / loop_s
    return {
        "coach_days_per_s": fleet_rate,
        "coaches": coaches,
        "days": days,
        "dt_s": env.dt_s,
        "steps": len(env.time),
        "fleet_seconds": fleet_s,
        "loop_coach_days_per_s": loop_rate,
        "loop_coaches": n_loop,
        "speedup_vs_loop": fleet_rate / loop_rate,
        "target": {"coach_days_per_s": TARGET_COACH_DAYS_PER_S},
        "target_met": fleet_rate >= TARGET_COACH_DAYS_PER_S,
        "machine": machine(),
    }


def text(d: dict) -> str:
    """One line: the fleet's and the loop's coach-days/s and the speed-up."""
    return (
        f"simulator: {d['coach_days_per_s']:.1f} coach-days/s for {d['coaches']} coaches × "
        f"{d['days']:g} day(s) at dt = {d['dt_s']:g} s; per-coach loop "
        f"{d['loop_coach_days_per_s']:.2f} coach-days/s; speed-up {d['speedup_vs_loop']:.0f}×"
    )
