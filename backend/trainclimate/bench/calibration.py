"""``bench calibrate``: the time to calibrate a twin per coach-week, and what simulating the
Jacobian's parameter sets as one fleet saves against one simulation per set."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from trainclimate.bench.common import machine

#: A coach-week's calibration (one parameter, one start) may take at most this long here. [s]
TARGET_COACH_WEEK_S = 300.0
#: The coach whose logs are calibrated (in service every day of the generated winter days).
COACH = "44A"


#: The fits timed by default: the envelope alone, and the envelope with the thermal capacities.
FITS = (("envelope_scale",), ("envelope_scale", "capacity_scale"))


def run(days: int = 7, fits: tuple[tuple[str, ...], ...] = FITS) -> dict:
    """Calibrate coach :data:`COACH` on ``days`` generated winter days (its envelope 20 % above
    the default); time one replay simulation, the Jacobian's seven parameter sets as one fleet
    and as seven simulations (the baseline, in the same run), and the whole calibration of each
    of ``fits`` (one start each, no bootstrap; the first gives the time per coach-week)."""
    from trainclimate.data import fleetlogs
    from trainclimate.data.dataset import build_dataset
    from trainclimate.data.trajectory import read_trajectories
    from trainclimate.sim.params import CoachParams
    from trainclimate.twin.calibration import calibrate
    from trainclimate.twin.knobs import CalibrationError, apply
    from trainclimate.twin.replay import replay, simulate
    from trainclimate.twin.validation import split_days

    truth = apply(CoachParams(), {"envelope_scale": 1.2})
    with tempfile.TemporaryDirectory(prefix="tc-bench-") as tmp:
        root = Path(tmp)
        fleetlogs.generate(
            root / "raw", campaigns=(fleetlogs.WINTER_SPRING,), max_days=days, max_coaches=2,
            coach_params=truth,
        )  # fmt: skip
        build_dataset(root / "raw", root / "out")
        mine = [
            t
            for t in read_trajectories(root / "out" / "trajectories_1min.parquet")
            if t.coach == COACH
        ]
    logged_days = len({t.time[0].date() for t in mine})
    train, _ = split_days(mine)
    rep = replay(train)
    sets = [apply(CoachParams(), {"envelope_scale": 1.0 + 0.01 * i}) for i in range(7)]

    def timed(f) -> float:
        t0 = time.perf_counter()
        f()
        return time.perf_counter() - t0

    one = timed(lambda: simulate(rep, sets[:1]))
    batched = timed(lambda: simulate(rep, sets))
    separate = timed(lambda: [simulate(rep, [s]) for s in sets])
    timings = {}
    for names in fits:
        t0 = time.perf_counter()
        try:
            fit = calibrate(COACH, mine, names, starts=1, bootstrap=0)
            outcome = {n: v["value"] for n, v in fit.fitted.items()}
        except CalibrationError as exc:
            outcome = {"refused": str(exc)}
        seconds = time.perf_counter() - t0
        timings[",".join(names)] = {
            "seconds": seconds,
            "seconds_per_coach_week": seconds * 7 / logged_days,
            "result": outcome,
        }
    per_week = timings[",".join(fits[0])]["seconds_per_coach_week"]
    return {
        "days_logged": logged_days,
        "trajectories": len(mine),
        "scored_training_minutes": int(rep.scored.sum()),
        "simulation_s": one,
        "jacobian_batched_s": batched,
        "jacobian_separate_s": separate,
        "batched_speedup": separate / batched,
        "fits": timings,
        "seconds_per_coach_week": per_week,
        "target": {"seconds_per_coach_week_max": TARGET_COACH_WEEK_S},
        "target_met": per_week <= TARGET_COACH_WEEK_S,
        "machine": machine(),
    }


def text(d: dict) -> str:
    """One line: the calibration per coach-week and the batched Jacobian's speed-up."""
    return (
        f"calibrate: {d['seconds_per_coach_week']:.0f} s per coach-week (envelope); "
        f"Jacobian of 7 sets as one fleet {d['jacobian_batched_s']:.1f} s against "
        f"{d['jacobian_separate_s']:.1f} s one by one ({d['batched_speedup']:.1f}×)"
    )
