"""``bench controller``: the controller's speed at the default model's setting (ρ = 12, T = 6) on
realistic inputs: one OCP solve three ways, the whole controller step and a fleet tick."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from trainclimate.bench.common import machine, percentiles_ms

#: The controller's targets: the fast path's median solve [ms], its speed-up over the naive
#: cvxpy formulation [-], a 1 000-coach tick [s].
TARGET = {"fast_median_ms": 1.0, "naive_over_fast": 20.0, "fleet_1000_tick_s": 2.0}


def run(n_steps: int = 1000, n_naive: int = 60, fleet: int = 1000) -> dict:
    """Controller speed at ρ = 12, T = 6 (the default model) on realistic inputs.

    All of it under the layer's default objective (:data:`~trainclimate.control.ocp.
    DEFAULT_OBJECTIVE`, what the service runs). One OCP solve three ways — the fast path (OSQP,
    matrices built once, warm-started), the cached cvxpy path (DPP, compiled once) and the naive
    cvxpy path (rebuilt every step) — each timed around ``solve`` on the same instances
    (``n_steps``, the first 200 for the cached cvxpy path, the first ``n_naive`` for the naive
    one), and the fast path of the paper's objective beside them as the baseline
    (``paper_fast_median_ms``); the whole controller step (checks, state estimate, T_opt, solve)
    on the fast path; and one fleet tick: ``fleet`` coaches, each with its own controller, one
    step each after a first tick has warmed them (setup not timed).

    Medians and 99th percentiles in ms; the fleet tick in s, scaled to 1000 coaches
    (``fleet_1000_tick_s``).
    """
    from trainclimate.control import DDPCController, DDPCProblem, OCPSettings, ReferenceProblem
    from trainclimate.control.coach_model import CoachModel
    from trainclimate.control.controller import t_opt
    from trainclimate.control.estimator import StateEstimator
    from trainclimate.control.ocp import DEFAULT_OBJECTIVE
    from trainclimate.predict.default import default_predictor

    predictor = default_predictor()
    cases = _instances(predictor, n_steps)
    model = CoachModel()
    est = StateEstimator(model)
    args = []
    for c in cases:  # the OCP's data, as the controller builds it
        est.run(c["y"], c["d"])
        x0 = est.temperatures
        x0[:3] = c["y"][-1]
        opt = t_opt(model, x0, c["d"][-1], c["d_future"], c["t_rule"], 1.0)
        args.append((c["y"], c["u"], c["d"], c["d_future"], c["t_rule"], opt, c["u_prev"]))

    settings = OCPSettings(objective=DEFAULT_OBJECTIVE)
    fast = _timed(DDPCProblem(predictor, settings).solve, args)
    paper = _timed(DDPCProblem(predictor, OCPSettings(objective="paper")).solve, args)
    dpp = _timed(ReferenceProblem(predictor, settings).solve, args[:200])
    naive = _timed(ReferenceProblem(predictor, settings, rebuild=True).solve, args[:n_naive])
    ctl = DDPCController(predictor, settings, model=model)
    step = []
    for c in cases:
        t0 = time.perf_counter()
        ctl.step(**c)
        step.append(time.perf_counter() - t0)

    controllers = [DDPCController(predictor, settings, model=model) for _ in range(fleet)]
    fleet_cases = [cases[i % len(cases)] for i in range(fleet)]
    for ctl, c in zip(controllers, fleet_cases, strict=True):
        ctl.step(**c)  # first tick: warm-up of the estimate and the solver
    t0 = time.perf_counter()
    reasons: dict[str, int] = {}
    for ctl, c in zip(controllers, fleet_cases, strict=True):
        r = ctl.step(**c)
        reasons[r.reason] = reasons.get(r.reason, 0) + 1
    fleet_s = time.perf_counter() - t0

    fast_med, fast_p99 = percentiles_ms(fast)
    paper_med, _ = percentiles_ms(paper)
    dpp_med, dpp_p99 = percentiles_ms(dpp)
    naive_med, naive_p99 = percentiles_ms(naive)
    step_med, step_p99 = percentiles_ms(step)
    return {
        "fast_median_ms": fast_med,
        "fast_p99_ms": fast_p99,
        "objective": DEFAULT_OBJECTIVE,
        "paper_fast_median_ms": paper_med,
        "cvxpy_dpp_median_ms": dpp_med,
        "cvxpy_dpp_p99_ms": dpp_p99,
        "cvxpy_naive_median_ms": naive_med,
        "cvxpy_naive_p99_ms": naive_p99,
        "naive_over_fast": naive_med / fast_med,
        "dpp_over_fast": dpp_med / fast_med,
        "controller_step_median_ms": step_med,
        "controller_step_p99_ms": step_p99,
        "fleet_1000_tick_s": fleet_s * 1000 / fleet,
        "fleet_coaches": fleet,
        "fleet_tick_reasons": reasons,
        "rho": predictor.rho,
        "horizon": predictor.horizon,
        "instances": len(cases),
        "target": TARGET,
        "target_met": fast_med <= TARGET["fast_median_ms"]
        and naive_med / fast_med >= TARGET["naive_over_fast"]
        and fleet_s * 1000 / fleet <= TARGET["fleet_1000_tick_s"],
        "machine": machine(),
    }


def text(d: dict) -> str:
    """Two lines: the three solves' medians in ms, the step's median in ms, the tick in s."""
    return (
        f"OCP solve (ρ = {d['rho']}, T = {d['horizon']}, {d['objective']}), median: fast "
        f"{d['fast_median_ms']:.3f} ms (p99 {d['fast_p99_ms']:.3f}; the paper's objective "
        f"{d['paper_fast_median_ms']:.3f} ms), cvxpy DPP "
        f"{d['cvxpy_dpp_median_ms']:.1f} ms, cvxpy rebuilt {d['cvxpy_naive_median_ms']:.1f} ms "
        f"({d['naive_over_fast']:.0f}× the fast path)\n"
        f"whole controller step {d['controller_step_median_ms']:.3f} ms median; "
        f"fleet tick of 1000 coaches {d['fleet_1000_tick_s']:.2f} s"
    )


def _timed(solve, items) -> list[float]:
    """``solve(*a)`` for each ``a`` of ``items``: the durations in s."""
    out = []
    for a in items:
        t0 = time.perf_counter()
        solve(*a)
        out.append(time.perf_counter() - t0)
    return out


def _instances(predictor, n: int, seed: int = 0) -> list[dict]:
    """``n`` realistic controller inputs: windows of the default dataset's 5-min trajectories
    (measured y, u, d and the true future d), T_rule from the rule curve; times in s since the
    epoch, temperatures in °C."""
    from trainclimate.coach.rule import RuleCurve
    from trainclimate.data.cache import default_dataset
    from trainclimate.data.trajectory import iter_trajectories

    rho, T = predictor.rho, predictor.horizon
    path = Path(default_dataset()) / "trajectories_5min.parquet"
    trajs = [t for t, _ in zip(iter_trajectories(path), range(400), strict=False)]
    trajs = [t for t in trajs if len(t) >= rho + T]
    rng = np.random.default_rng(seed)
    rule = RuleCurve()
    out = []
    for _ in range(n):
        t = trajs[rng.integers(len(trajs))]
        k = int(rng.integers(0, len(t) - rho - T + 1))
        d_all = t.d[k : k + rho + T]
        out.append(
            {
                "now_s": float(t.time[k + rho - 1].timestamp()),
                "sample_times_s": np.array([x.timestamp() for x in t.time[k : k + rho]]),
                "y": t.y[k : k + rho],
                "u": t.u[k : k + rho - 1, 0],
                "d": d_all[:rho],
                "d_future": d_all[rho:],
                "t_rule": rule(d_all[rho - 1 :, 0]),
                "u_prev": float(t.u[k + rho - 2, 0]),
            }
        )
    return out
