"""The DDPC layer's step for one coach: measurements in, T_ref out — always a safe one.

At each tick t (every sampling period) the caller hands over the measured samples up to t (y, the
applied u, d), the forecast, T_rule over the horizon and u(t−1). The step

1. checks its inputs; any problem gives the safe rule-based setpoint with a reason code
   (:data:`REASONS`) — warm-up until ρ valid samples exist (the paper's 1-hour lead-in), stale or
   missing samples, NaN or out-of-range values, no predictor or one that does not match the
   sampling — and never raises into the caller;
2. updates the state estimate (:class:`~.estimator.StateEstimator`) with the newest sample;
3. computes T_opt: the coach's thermal model run open loop with the HVAC off over the horizon
   from the estimate, driven by the forecast, its mean room temperature projected onto
   [T_rule − T_max, T_rule + T_max] (paper, Section III.C);
4. solves the optimal control problem (:class:`~.ocp.DDPCProblem`) and applies u*(0|t); a solver
   that fails, finds the problem infeasible or overruns its time limit gives the fallback.

A fallback returns to T_rule no faster than the rate limit ΔT_max allows (the comfort reason for
that limit applies to the way back as well). The output always lies within T_rule ± u_band.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from trainclimate.control.coach_model import CoachModel
from trainclimate.control.estimator import StateEstimator
from trainclimate.control.ocp import DDPCProblem, OCPSettings
from trainclimate.predict.base import MultistepPredictor
from trainclimate.predict.setting import HORIZON, RHO, SAMPLING_MIN

#: After how many sampling periods without a new sample the measurements are stale.
STALE_PERIODS = 2

#: Why a step gave the setpoint it gave.
REASONS = {
    "ok": "DDPC optimum applied",
    "inactive": "the layer is switched off for this coach (T_ref = T_rule)",
    "warmup": "fewer than ρ valid samples (lead-in)",
    "stale": "no new sample within the stale limit (2 sampling periods by default)",
    "missing_samples": "a gap in the last ρ samples",
    "invalid_data": "NaN or out-of-range measurement or forecast",
    "invalid_rule": "T_rule missing or not finite",
    "no_predictor": "no prediction model",
    "incompatible_predictor": "the model's sampling time or size does not fit",
    "infeasible": "the optimal control problem is infeasible",
    "solver_timeout": "the solver overran its time limit",
    "solver_failed": "the solver did not reach an optimum",
    "error": "unexpected error in the controller",
}
#: Physically possible ranges of y (°C), u (°C) and d = [T_amb °C, Q_Gt, Q_Gs W/m², P %, V km/h].
Y_RANGE = (-30.0, 60.0)
U_RANGE = (10.0, 35.0)
D_RANGES = ((-40.0, 50.0), (0.0, 1500.0), (0.0, 1500.0), (0.0, 300.0), (0.0, 250.0))


@dataclass
class StepResult:
    """What one controller step decided, and why, with the trajectories behind it.

    Attributes
    ----------
    t_ref_c : float
        The setpoint T_ref to apply. [°C]
    source : str
        ``"ddpc"`` (the optimum), ``"rule"`` (lead-in or inactive), ``"fallback"`` or
        ``"edge"`` (:class:`BandEdgeController`).
    reason : str
        A key of :data:`REASONS`.
    t_rule_c : float
        T_rule(0|t). [°C]
    detail : str
        Human-readable detail of the reason.
    t_opt_c : numpy.ndarray of shape (T+1,) or None
        T_opt(k|t), k = 0 … T, when computed. [°C]
    u_plan_c : numpy.ndarray of shape (T+1,) or None
        The optimal u(0|t) … u(T|t). [°C]
    y_pred_c : numpy.ndarray of shape (T, 3) or None
        The predicted room temperatures y(1|t) … y(T|t). [°C]
    solve_time_s, step_time_s : float
        Time of the solver and of the whole step. [s]
    solver_status : str
        The solver's status, when it ran.
    extra : dict
        ``objective`` (K²) and ``room_heat_w`` (estimated unmeasured heat per room, W) after a
        solved step.
    """

    t_ref_c: float
    source: str
    reason: str
    t_rule_c: float
    detail: str = ""
    t_opt_c: np.ndarray | None = None
    u_plan_c: np.ndarray | None = None
    y_pred_c: np.ndarray | None = None
    solve_time_s: float = 0.0
    step_time_s: float = 0.0
    solver_status: str = ""
    extra: dict = field(default_factory=dict)


def t_opt(
    model: CoachModel,
    x0: np.ndarray,
    d_now: np.ndarray,
    d_future: np.ndarray,
    t_rule: np.ndarray,
    t_max: float,
) -> np.ndarray:
    """The reference temperature T_opt(k|t), k = 0 … T, of the costs J_u and J_y.

    The mean room temperature of an open-loop run of the coach model with the HVAC off
    (Q_hvac = 0) from state ``x0``, projected onto [T_rule − t_max, T_rule + t_max].

    Parameters
    ----------
    model : CoachModel
        The controller's coach model, discretised at the controller's period.
    x0 : numpy.ndarray of shape (9,)
        Current temperatures [T_room; T_inv; T_chassis] (°C), e.g. the state estimate.
    d_now : numpy.ndarray of shape (5,)
        Disturbance acting over [t, t+1): [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats,
        V km/h].
    d_future : numpy.ndarray of shape (T, 5)
        Forecast; row j acts over [t+j+1, t+j+2) (the last row is not needed).
    t_rule : numpy.ndarray of shape (T+1,)
        T_rule(k|t), k = 0 … T. [°C]
    t_max : float
        Comfort half-band T_max. [K]

    Returns
    -------
    numpy.ndarray of shape (T+1,)
        T_opt(k|t). [°C]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.C.
    """
    T = len(t_rule) - 1
    run = model.free_run(x0, np.vstack([d_now, d_future[: T - 1]]))
    mean_room = np.concatenate([[x0[:3].mean()], run[:, :3].mean(axis=1)])
    return np.clip(mean_room, t_rule - t_max, t_rule + t_max)


def _in_range(values: np.ndarray, ranges) -> bool:
    values = np.atleast_2d(values)
    lo = np.array([r[0] for r in ranges])
    hi = np.array([r[1] for r in ranges])
    return bool(np.all(np.isfinite(values)) and np.all((values >= lo) & (values <= hi)))


class DDPCController:
    """The DDPC layer of one coach (stateful: the state estimate and the solver's warm start).

    Receives T_rule and the measurements and outputs T_ref (Figure 4 [1]_); see the module
    docstring for the step and its fallbacks.

    Parameters
    ----------
    predictor : MultistepPredictor or None
        A fitted multistep predictor; None makes every step fall back.
    settings : OCPSettings, optional
        The optimal control problem's weights and bounds (default: :class:`OCPSettings`).
    sampling_min : float, default 5.0
        The controller's period; must match the predictor's sampling time. [min]
    model : CoachModel, optional
        The coach model for T_opt and the estimator (default: the fleet's default coach,
        discretised at the period).
    rho, horizon : int, optional
        ρ and T when there is no predictor (default 12 and 6); otherwise the predictor's.

    Attributes
    ----------
    needs_predictor : bool
        Whether steps without a (compatible) predictor fall back (True here).
    problem : DDPCProblem or None
        The optimal control problem, None without a compatible predictor.
    estimator : StateEstimator
        The state estimate of the coach.
    period_s : float
        The controller's period. [s]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.C, Figure 4.
    """

    needs_predictor = True

    def __init__(
        self,
        predictor: MultistepPredictor | None,
        settings: OCPSettings | None = None,
        *,
        sampling_min: float = SAMPLING_MIN,
        model: CoachModel | None = None,
        rho: int | None = None,
        horizon: int | None = None,
        stale_periods: int = STALE_PERIODS,
    ):
        self.settings = settings or OCPSettings()
        self.stale_periods = int(stale_periods)
        self.sampling_min = float(sampling_min)
        self.period_s = self.sampling_min * 60.0
        self.model = model or CoachModel(dt_s=self.period_s)
        self.estimator = StateEstimator(self.model)
        self.predictor = predictor
        self.problem: DDPCProblem | None = None
        self._incompatible = ""
        if predictor is not None:
            step = predictor.sampling_min
            if step is not None and abs(float(step) - self.sampling_min) > 1e-9:
                self._incompatible = (
                    f"the model is for {float(step):g}-min samples, the controller runs every "
                    f"{self.sampling_min:g} min"
                )
            elif abs(self.model.dt_s - self.period_s) > 1e-9:
                self._incompatible = "the coach model's step differs from the sampling period"
            else:
                self.problem = DDPCProblem(predictor, self.settings)
        self._last_sample_s: float | None = None
        self.rho = predictor.rho if predictor is not None else int(rho or RHO)
        self.horizon = predictor.horizon if predictor is not None else int(horizon or HORIZON)

    # --- the step ------------------------------------------------------------------------------
    def step(
        self,
        *,
        now_s: float,
        sample_times_s: np.ndarray,
        y: np.ndarray,
        u: np.ndarray,
        d: np.ndarray,
        d_future: np.ndarray,
        t_rule: np.ndarray,
        u_prev: float,
    ) -> StepResult:
        """One controller tick: measurements in, a safe T_ref out. Never raises.

        Parameters
        ----------
        now_s : float
            The tick's time, seconds since the Unix epoch (UTC). [s]
        sample_times_s : numpy.ndarray of shape (m,)
            Times of the measured samples, oldest first, the last one normally ``now_s``. [s]
        y : numpy.ndarray of shape (m, 3)
            Room temperatures up, mid, low measured by those times. [°C]
        u : numpy.ndarray of shape (m − 1,)
            Setpoints applied over the intervals between the samples. [°C]
        d : numpy.ndarray of shape (m, 5)
            Disturbance [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h] over
            [sample, sample + period); the last row the current interval's, as forecast.
        d_future : numpy.ndarray of shape (T, 5)
            The forecast beyond, as ``d``.
        t_rule : numpy.ndarray of shape (T+1,)
            T_rule(k|t) for k = 0 … T. [°C]
        u_prev : float
            The setpoint applied over the last interval, u(t−1). [°C]

        Returns
        -------
        StepResult
            The setpoint (within T_rule ± ``u_band`` whenever T_rule is valid), its source
            and reason; any error gives the fallback with reason ``"error"``.
        """
        t0 = time.perf_counter()
        try:
            result = self._step(now_s, sample_times_s, y, u, d, d_future, t_rule, u_prev)
        except Exception as exc:  # the caller must always get a safe setpoint
            result = self._fallback("error", t_rule, u_prev, f"{type(exc).__name__}: {exc}")
        result.step_time_s = time.perf_counter() - t0
        return result

    def _fallback(self, reason: str, t_rule, u_prev, detail: str = "") -> StepResult:
        """T_rule, approached at most ΔT_max per step from u(t−1), inside T_rule ± u_band."""
        s = self.settings
        try:
            rule0 = float(np.asarray(t_rule, dtype=float).ravel()[0])
        except (TypeError, ValueError, IndexError):
            rule0 = float("nan")
        try:  # this is the last resort: it must not raise on a u(t−1) of the wrong type either
            u_prev = float(u_prev)
        except (TypeError, ValueError):
            u_prev = float("nan")
        if not np.isfinite(rule0):
            # nothing safe to compute: hold the last setpoint (the HVAC keeps what it has)
            held = float(u_prev) if np.isfinite(u_prev) else float("nan")
            detail = detail or REASONS["invalid_rule"]
            return StepResult(held, "fallback", "invalid_rule", rule0, detail)
        target = rule0
        if np.isfinite(u_prev):
            target = float(u_prev) + float(np.clip(rule0 - u_prev, -s.du_max, s.du_max))
        target = float(np.clip(target, rule0 - s.u_band, rule0 + s.u_band))
        source = "rule" if reason == "warmup" else "fallback"
        return StepResult(target, source, reason, rule0, detail or REASONS[reason])

    def _step(self, now_s, sample_times_s, y, u, d, d_future, t_rule, u_prev) -> StepResult:
        s = self.settings
        t_rule = np.asarray(t_rule, dtype=float).ravel()
        if self.needs_predictor and self.predictor is None:
            return self._fallback("no_predictor", t_rule, u_prev)
        if self.needs_predictor and self.problem is None:
            return self._fallback("incompatible_predictor", t_rule, u_prev, self._incompatible)
        rho, T = self.rho, self.horizon
        if t_rule.shape != (T + 1,) or not np.all(np.isfinite(t_rule)):
            return self._fallback("invalid_rule", t_rule, u_prev)
        times = np.asarray(sample_times_s, dtype=float).ravel()
        y = np.asarray(y, dtype=float).reshape(-1, 3)
        u = np.asarray(u, dtype=float).ravel()
        d = np.asarray(d, dtype=float).reshape(-1, 5)
        d_future = np.asarray(d_future, dtype=float).reshape(-1, 5)
        if len(times) < rho or len(y) < rho or len(d) < rho or len(u) < rho - 1:
            return self._fallback("warmup", t_rule, u_prev, f"{len(times)} of {rho} samples")
        if now_s - times[-1] >= self.stale_periods * self.period_s:
            self._last_sample_s = None
            age = f"last sample {now_s - times[-1]:.0f} s old"
            return self._fallback("stale", t_rule, u_prev, age)
        recent = times[-rho:]
        if np.any(np.abs(np.diff(recent) - self.period_s) > 1.0):
            self._last_sample_s = None
            return self._fallback("missing_samples", t_rule, u_prev)
        y_p, d_p, u_p = y[-rho:], d[-rho:], u[len(u) - (rho - 1) :]
        if (
            not _in_range(y_p, [Y_RANGE] * 3)
            or not _in_range(d_p, D_RANGES)
            or not _in_range(d_future, D_RANGES)
            or len(d_future) != T
            or not _in_range(u_p[:, None], [U_RANGE])
            or not np.isfinite(u_prev)
        ):
            self._last_sample_s = None
            return self._fallback("invalid_data", t_rule, u_prev)

        # the state estimate: continue the filter with the newest sample, or rebuild it over ρ
        if self._last_sample_s is not None and abs(recent[-2] - self._last_sample_s) < 1.0:
            self.estimator.update(d_p[-2], y_p[-1])
        else:
            self.estimator.run(y_p, d_p)
        self._last_sample_s = float(recent[-1])
        x0 = self.estimator.temperatures
        x0[:3] = y_p[-1]
        opt = t_opt(self.model, x0, d_p[-1], d_future, t_rule, s.t_max)

        return self._decide(y_p, u_p, d_p, d_future, t_rule, opt, float(u_prev))

    def _decide(self, y_p, u_p, d_p, d_future, t_rule, opt, u_prev) -> StepResult:
        """Solve the OCP and apply u*(0|t) (or fall back)."""
        s = self.settings
        sol = self.problem.solve(y_p, u_p, d_p, d_future, t_rule, opt, u_prev)
        if not sol.solved:
            status = sol.status.lower()
            if "infeasible" in status:
                reason = "infeasible"
            elif "time" in status:
                reason = "solver_timeout"
            else:
                reason = "solver_failed"
            result = self._fallback(reason, t_rule, u_prev, f"solver status: {sol.status}")
            result.t_opt_c, result.solver_status = opt, sol.status
            return result
        if sol.solve_time_s > s.time_limit_s:
            result = self._fallback("solver_timeout", t_rule, u_prev, f"{sol.solve_time_s:.3f} s")
            result.t_opt_c, result.solver_status = opt, sol.status
            return result
        u0 = float(sol.u[0])
        # the optimum satisfies (6) and (7) to the solver's tolerance; make them exact
        u0 = float(np.clip(u0, u_prev - s.du_max, u_prev + s.du_max))
        u0 = float(np.clip(u0, t_rule[0] - s.u_band, t_rule[0] + s.u_band))
        return StepResult(
            t_ref_c=u0,
            source="ddpc",
            reason="ok",
            t_rule_c=float(t_rule[0]),
            t_opt_c=opt,
            u_plan_c=sol.u,
            y_pred_c=sol.y,
            solve_time_s=sol.solve_time_s,
            solver_status=sol.status,
            extra={"objective": sol.objective, "room_heat_w": self.estimator.room_heat_w},
        )


class BandEdgeController(DDPCController):
    """The band-edge reference (the paper's "trivial controller"): T_ref set straight to T_opt.

    It applies T_opt(1|t) — where the coach would drift in the coming interval with the HVAC off,
    projected onto the comfort band — computed like the DDPC layer's T_opt, but from the true
    future disturbances (give it a perfect forecast) and with no prediction model, no rate limit
    and no optimisation. It measures how much of the achievable saving the DDPC layer gets.
    Steps report ``source`` ``"edge"``.

    Parameters
    ----------
    settings : OCPSettings, optional
        Gives T_max and ``u_band`` (default: :class:`OCPSettings`).
    sampling_min : float, default 5.0
        The controller's period. [min]
    rho, horizon : int, default 12, 6
        Lead-in ρ (samples before it acts) and horizon T.
    model : CoachModel, optional
        The coach model for T_opt (default: the fleet's default coach).

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section III.C.
    """

    needs_predictor = False

    def __init__(
        self,
        settings: OCPSettings | None = None,
        *,
        sampling_min: float = SAMPLING_MIN,
        rho: int = RHO,
        horizon: int = HORIZON,
        model: CoachModel | None = None,
        stale_periods: int = STALE_PERIODS,
    ):
        super().__init__(
            None,
            settings,
            sampling_min=sampling_min,
            model=model,
            rho=rho,
            horizon=horizon,
            stale_periods=stale_periods,
        )

    def _decide(self, y_p, u_p, d_p, d_future, t_rule, opt, u_prev) -> StepResult:
        s = self.settings
        t_ref = float(np.clip(opt[1], t_rule[0] - s.u_band, t_rule[0] + s.u_band))
        return StepResult(t_ref, "edge", "ok", float(t_rule[0]), t_opt_c=opt)
