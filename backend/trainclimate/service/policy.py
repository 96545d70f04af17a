"""The decision policy: the setpoint for one coach at one tick, from plain inputs.

:func:`decide` takes the coach, its controller samples at the tick, the override in force, the
tick, the settings and the coach's DDPC controller (or None without a predictor model), and
touches no database: the scheduler (:mod:`trainclimate.service.scheduler`) loads the inputs and
stores the :class:`Decision`. In this order:

1. an override in force (source ``override``, clipped to T_rule ± 2 K; it needs a T_rule);
2. no telemetry for ``stale_periods`` periods, or no T_rule (``fallback``, ``stale``: T_rule, or
   without one the T_ref applied last);
3. the layer switched off for the coach (``rule``, ``inactive``: T_ref = T_rule);
4. the train's guard has tripped: the pair's own trial says the layer costs energy
   (``rule``, ``costing_energy``: T_ref = T_rule; :mod:`trainclimate.analysis.guard`);
5. not in regular mode (``rule``, ``not_regular``);
6. no predictor model yet (``rule``, ``no_model``);
7. otherwise the DDPC step (:meth:`~trainclimate.control.DDPCController.step`), which falls back
   to T_rule itself, with a reason code, on any problem.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import TYPE_CHECKING

import numpy as np

from trainclimate.analysis.guard import REASON, describe
from trainclimate.coach.setpoint import U_BAND_K

if TYPE_CHECKING:
    from trainclimate.control import DDPCController
    from trainclimate.control.controller import StepResult
    from trainclimate.service.settings import Settings
    from trainclimate.service.store.models import Coach, Override
    from trainclimate.service.store.telemetry import Samples


@dataclass
class Decision:
    """What a tick decided for one coach (a setpoint row's content): T_ref and T_rule (°C),
    source and reason codes, a detail in words, the solve and step times (ms) and the predicted
    trajectory of a DDPC step."""

    t_ref_c: float | None
    t_rule_c: float | None
    source: str
    reason: str
    detail: str = ""
    solve_time_ms: float | None = None
    step_time_ms: float | None = None
    predicted: dict | None = None
    extra: dict = field(default_factory=dict)


def _finite(value) -> float | None:
    return float(value) if value is not None and np.isfinite(value) else None


def decide(
    coach: Coach,
    samples: Samples,
    override: Override | None,
    tick: datetime,
    settings: Settings,
    controller: Callable[[], DDPCController] | None,
    guard: dict | None = None,
) -> Decision:
    """The setpoint for ``coach`` at ``tick`` (see the module docstring for the order).

    ``samples`` are the coach's controller samples at the tick; ``override`` the one in force, if
    any; ``settings`` give the sampling period (min) and after how many periods without telemetry
    the coach is stale. ``controller`` returns the coach's controller and is called only when the
    DDPC step is reached (building a controller sets up its optimisation problem); None means there
    is no predictor model yet. ``guard`` is the figures of the train's tripped guard
    (:func:`trainclimate.service.store.guard.tripped`), None while it watches.
    """
    t_rule = _finite(samples.t_rule_now)
    period = timedelta(minutes=settings.sampling_min)
    stale_after = tick - settings.stale_periods * period
    fresh = samples.last_time_s is not None and samples.last_time_s > stale_after.timestamp()
    if override is not None and t_rule is not None:
        value = float(np.clip(override.t_ref_c, t_rule - U_BAND_K, t_rule + U_BAND_K))
        return Decision(value, t_rule, "override", "override", f"override #{override.id}")
    if t_rule is None or not fresh:
        last = _finite(samples.u_prev)
        detail = f"no telemetry for {settings.stale_periods} sampling periods"
        t_ref = t_rule if t_rule is not None else last
        return Decision(t_ref, t_rule, "fallback", "stale", detail)
    if not coach.ddpc_active:
        return Decision(t_rule, t_rule, "rule", "inactive", "the layer is off for this coach")
    if guard is not None:
        detail = f"the layer cost this pair energy: {describe(guard)}; an operator re-enables it"
        return Decision(t_rule, t_rule, "rule", REASON, detail)
    if not samples.regular:
        return Decision(t_rule, t_rule, "rule", "not_regular", "the HVAC is not in regular mode")
    if controller is None:
        detail = "no predictor model yet (it is being prepared)"
        return Decision(t_rule, t_rule, "rule", "no_model", detail)
    ctl = controller()
    T = ctl.horizon
    d, d_future = disturbances(samples, T)
    result = ctl.step(
        now_s=tick.timestamp(),
        sample_times_s=samples.times_s,
        y=samples.y,
        u=samples.u,
        d=d,
        d_future=d_future,
        t_rule=np.full(T + 1, t_rule),
        u_prev=samples.u_prev if np.isfinite(samples.u_prev) else t_rule,
    )
    return _from_step(result)


def disturbances(samples: Samples, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """The controller's disturbances at the tick: d at the samples (m, 5), the last one the
    current interval's, and the forecast (``horizon``, 5) — the current interval's persisted (no
    external forecast yet)."""
    d_now = samples.d_now if samples.d_now is not None else np.full(5, np.nan)
    d = np.vstack([samples.d_past, d_now]) if len(samples.d_past) else d_now[None, :]
    return d[-len(samples.times_s) :], np.tile(d_now, (horizon, 1))


def shadow_prediction(predictor, samples: Samples, predicted: dict | None) -> np.ndarray | None:
    """What ``predictor`` (a candidate model) predicts from the samples the active model's
    controller used and the setpoints it planned, u(0|t) … u(T|t): y(1|t) … y(T|t), (T, 3) in °C
    — the same arithmetic as the active model's own stored prediction. None when there is no
    plan, the candidate's ρ, T differ from the plan's, or the samples are too few or not finite."""
    u_plan = np.asarray((predicted or {}).get("u_plan_c", []), float)
    rho, T = predictor.rho, predictor.horizon
    if u_plan.shape != (T + 1,) or len(samples.times_s) < rho:
        return None
    d, d_future = disturbances(samples, T)
    u_past = np.append(np.asarray(samples.u, float)[len(samples.u) - (rho - 1) :], u_plan[0])
    try:
        y = predictor.predict(samples.y[-rho:], u_past, d[-rho:], u_plan[1:], d_future)
    except ValueError:
        return None
    return y if np.all(np.isfinite(y)) else None


def _from_step(result: StepResult) -> Decision:
    """A controller step's result as a decision (times in ms; the trajectories as lists)."""
    predicted = None
    if result.t_opt_c is not None:
        predicted = {"t_opt_c": np.asarray(result.t_opt_c).tolist()}
        if result.u_plan_c is not None:
            predicted["u_plan_c"] = np.asarray(result.u_plan_c).tolist()
        if result.y_pred_c is not None:
            predicted["y_pred_c"] = np.asarray(result.y_pred_c).tolist()
    return Decision(
        t_ref_c=_finite(result.t_ref_c),
        t_rule_c=_finite(result.t_rule_c),
        source=result.source,
        reason=result.reason,
        detail=result.detail,
        solve_time_ms=result.solve_time_s * 1e3 if result.source == "ddpc" else None,
        step_time_ms=result.step_time_s * 1e3,
        predicted=predicted,
    )
