"""The DDPC layer in the loop with the simulator (paper, Section IV.B and Figure 4).

:class:`ClosedLoop` is a setpoint policy for :class:`~trainclimate.sim.simulator.FleetSimulator`:
the simulator keeps its own 10-s step (the HVAC's PID and the physics), and every ``tick_s``
(5 min) each coach's controller gets the samples the fleet's telemetry would give it, by the
same convention as the training data (:mod:`trainclimate.data.trajectory`):

- y(t): the mean of the coach's sensor readings in the minute up to t;
- u(t): the setpoint applied over [t, t + Δ) (its mean over the interval);
- d(t) = [T_amb, Q_Gt, Q_Gs, P, V]: their means over [t, t + Δ) — known afterwards, so the
  current interval's comes from the forecast, as do the T intervals after it.

The controller only acts in regular mode (the mode its model was trained on); any other mode,
and the lead-in after it, run the rule-based architecture (T_ref = T_rule). Between ticks T_ref is
held, kept within the driver's limit T_rule ± 2 K of the simulator's current T_rule.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from trainclimate.coach.rule import MODE_REGULAR
from trainclimate.coach.setpoint import apply_setpoint
from trainclimate.control.coach_model import CoachModel
from trainclimate.control.controller import BandEdgeController, DDPCController, StepResult
from trainclimate.control.forecast import (
    Forecaster,
    NoisyForecast,
    PerfectForecast,
    PersistenceForecast,
)
from trainclimate.control.ocp import OCPSettings
from trainclimate.predict.base import MultistepPredictor
from trainclimate.predict.setting import HORIZON, RHO
from trainclimate.sim.simulator import FleetSimulator

#: Driver/operator limit around T_rule (K), also the HVAC interface's.


@dataclass
class TickLog:
    """Every tick of every coach, as three parallel lists.

    Attributes
    ----------
    step : list of int
        Simulator step index of each tick.
    coach : list of int
        Coach index of each tick.
    results : list of StepResult
        What the controller decided at each tick.
    """

    step: list[int] = field(default_factory=list)
    coach: list[int] = field(default_factory=list)
    results: list[StepResult] = field(default_factory=list)

    def of_coach(self, coach: int) -> TickLog:
        """The ticks of one coach.

        Parameters
        ----------
        coach : int
            Coach index.

        Returns
        -------
        TickLog
            A new log holding only that coach's ticks, in order.
        """
        out = TickLog()
        for k, c, r in zip(self.step, self.coach, self.results, strict=True):
            if c == coach:
                out.step.append(k)
                out.coach.append(c)
                out.results.append(r)
        return out


def interval_means(sim: FleetSimulator, steps_per_tick: int) -> np.ndarray:
    """The disturbance d averaged over every controller interval of the run.

    Parameters
    ----------
    sim : FleetSimulator
        Its environment gives the series.
    steps_per_tick : int
        Simulator steps per controller interval; a last incomplete interval is padded with the
        last sample.

    Returns
    -------
    numpy.ndarray of shape (ticks, coaches, 5)
        [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h] per interval and coach.
    """
    env = sim.env
    fields = (env.t_amb_c, env.q_roof_w_m2, env.q_side_w_m2, env.occupancy_pct, env.speed_kmh)
    s = len(env.time)
    n_ticks = -(-s // steps_per_tick)
    pad = n_ticks * steps_per_tick - s
    out = []
    for f in fields:
        arr = np.concatenate([f, np.repeat(f[-1:], pad, axis=0)]) if pad else np.asarray(f)
        out.append(arr.reshape(n_ticks, steps_per_tick, -1).mean(axis=1))
    return np.stack(out, axis=-1)


class ClosedLoop:
    """A setpoint policy running one controller per coach (see the module docstring).

    Pass it to :meth:`~trainclimate.sim.simulator.FleetSimulator.run`; called with the step
    index and the simulator, it returns T_ref (coaches,) in °C.

    Parameters
    ----------
    sim : FleetSimulator
        The simulator it drives.
    controllers : list of DDPCController or None
        The controller of each coach, or None for a coach under the rule-based architecture
        (the deactivated coach of a pair).
    forecast : str or list of str, default "perfect"
        ``"perfect"``, ``"persistence"`` or ``"noisy"``, for all coaches or one per coach.
    tick_s : float, default 300.0
        The controller's period, a multiple of the simulator's step. [s]
    seed : int or list of int, default 0
        Seed of the noisy forecasts: plus the coach index, or one per coach.
    on_tick : callable, optional
        Called with (step, coach, StepResult) after each controller step.
    disconnected : numpy.ndarray of bool, shape (steps, coaches), optional
        The link to the coach is lost: no telemetry reaches the controller and no command the
        HVAC, which falls back to its own T_rule.
    overridden : numpy.ndarray of bool, shape (steps, coaches), optional
        The coach's commands are overwritten by T_rule (a communication error) while its
        telemetry still arrives.
    active_from : numpy.ndarray of int, shape (coaches,), optional
        The step before which a controller only gathers its lead-in and the coach runs on
        T_rule (the paper activated the layer at a chosen time).
    active : numpy.ndarray of bool, shape (steps, coaches), optional
        Where the layer is switched on for the coach (default: everywhere), as a trial's plan
        switches it day by day. While it is off the coach runs on T_rule and its controller does
        not step, but its telemetry is still gathered (as the service stores it), so the layer
        acts from its first tick once switched on again.

    Attributes
    ----------
    log : TickLog
        Every tick of every coach.
    d_true : numpy.ndarray of shape (ticks, coaches, 5)
        The true interval means of d (:func:`interval_means`).

    Raises
    ------
    ValueError
        If the numbers of controllers, forecasts or seeds do not match the coaches, the period
        is not a multiple of the step, an event or activity mask has the wrong shape, or a
        forecast is unknown.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Sections IV.B and V, Figure 4.
    """

    def __init__(
        self,
        sim: FleetSimulator,
        controllers: list[DDPCController | None],
        *,
        forecast: str | list[str] = "perfect",
        tick_s: float = 300.0,
        seed: int | list[int] = 0,
        on_tick: Callable[[int, int, StepResult], None] | None = None,
        disconnected: np.ndarray | None = None,
        overridden: np.ndarray | None = None,
        active_from: np.ndarray | None = None,
        active: np.ndarray | None = None,
    ):
        n = sim.env.n_coaches
        if len(controllers) != n:
            raise ValueError(f"{len(controllers)} controllers for {n} coaches")
        self.sim = sim
        self.controllers = controllers
        self.steps_per_tick = round(tick_s / sim.dt_s)
        if abs(self.steps_per_tick * sim.dt_s - tick_s) > 1e-9:
            raise ValueError("the controller period must be a multiple of the simulator's step")
        self.tick_s = tick_s
        self.d_true = interval_means(sim, self.steps_per_tick)
        kinds = [forecast] * n if isinstance(forecast, str) else list(forecast)
        if len(kinds) != n:
            raise ValueError(f"{len(kinds)} forecasts for {n} coaches")
        seeds = [seed + c for c in range(n)] if np.ndim(seed) == 0 else list(seed)
        if len(seeds) != n:
            raise ValueError(f"{len(seeds)} forecast seeds for {n} coaches")
        self.forecasters = [self._forecaster(kind, c, seeds[c]) for c, kind in enumerate(kinds)]
        self.held = np.full(n, np.nan)
        self.history = [_History() for _ in range(n)]
        self.log = TickLog()
        self.on_tick = on_tick
        shape = sim.env.mode.shape
        self.disconnected = np.zeros(shape, bool) if disconnected is None else disconnected
        self.overridden = np.zeros(shape, bool) if overridden is None else overridden
        self.active_from = np.zeros(n, int) if active_from is None else np.asarray(active_from)
        self.active = np.ones(shape, bool) if active is None else np.asarray(active, bool)
        masks = (self.disconnected, self.overridden, self.active)
        if any(m.shape != shape for m in masks):
            raise ValueError(f"the masks must have the shape (steps, coaches) = {shape}")

    def _forecaster(self, kind: str, coach: int, seed: int) -> Forecaster:
        d_true = self.d_true  # not ``self``: a loop → forecaster → loop cycle would keep the
        # simulator's arrays alive until the garbage collector's next full pass

        def truth(tick: int, steps: int) -> np.ndarray:
            idx = np.clip(np.arange(tick, tick + steps), 0, len(d_true) - 1)
            return d_true[idx, coach]

        if kind == "perfect":
            return PerfectForecast(truth)
        if kind == "persistence":
            return PersistenceForecast()
        if kind == "noisy":
            return NoisyForecast(truth, seed=seed)
        raise ValueError(f"unknown forecast {kind!r} (perfect, persistence, noisy)")

    def __call__(self, k: int, sim: FleetSimulator) -> np.ndarray:
        """T_ref (coaches,) in °C for step ``k``: the held setpoint, or T_rule, within ±2 K."""
        if k % self.steps_per_tick == 0:
            self._tick(k, sim)
        rule = sim.t_rule(k)
        applied = (
            (sim.env.mode[k] == MODE_REGULAR)
            & (k >= self.active_from)
            & self.active[k]
            & ~self.disconnected[k]
            & ~self.overridden[k]
        )
        return apply_setpoint(self.held, rule, applied)

    def _tick(self, k: int, sim: FleetSimulator) -> None:
        tick = k // self.steps_per_tick
        spt = self.steps_per_tick
        rec = sim.result()
        env = sim.env
        t_now = float(env.time[k].timestamp())
        minute = max(1, round(60.0 / sim.dt_s))
        for c, controller in enumerate(self.controllers):
            hist = self.history[c]
            if controller is None:
                continue
            if k == 0:
                continue
            interval = slice(k - spt, k)
            regular = bool(np.all(env.mode[interval, c] == MODE_REGULAR)) and (
                env.mode[k, c] == MODE_REGULAR
            )
            if not regular:
                hist.clear()
                self.held[c] = np.nan
                continue
            # close the interval just ended, then add the new sample — unless the link is down
            if not self.disconnected[k, c]:
                if hist.times:
                    hist.u.append(float(rec.t_ref_c[interval, c].mean()))
                    hist.d.append(self.d_true[tick - 1, c])
                y_now = rec.t_room_meas_c[k - minute : k, c].mean(axis=0)
                hist.add(t_now, y_now, controller.rho)
            if not hist.times:
                continue
            if not self.active[k, c]:
                self.held[c] = np.nan
                continue
            T = controller.horizon
            fc = self.forecasters[c].forecast(tick - 1, T + 1, self.d_true[tick - 1, c])
            t_rule = controller_rule(sim, fc[:, 0])
            u_prev = float(rec.t_ref_c[k - 1, c])  # what the HVAC applied last
            result = controller.step(
                now_s=t_now,
                sample_times_s=np.array(hist.times),
                y=np.array(hist.y),
                u=np.array(hist.u),
                d=np.vstack([*hist.d, fc[0]]) if hist.d else fc[:1],
                d_future=fc[1:],
                t_rule=t_rule,
                u_prev=u_prev,
            )
            if k < self.active_from[c]:
                result.source, result.reason = "rule", "inactive"
            self.held[c] = result.t_ref_c
            self.log.step.append(k)
            self.log.coach.append(c)
            self.log.results.append(result)
            if self.on_tick:
                self.on_tick(k, c, result)


def controller_rule(sim: FleetSimulator, t_amb_forecast: np.ndarray) -> np.ndarray:
    """T_rule(k|t), k = 0 … T, from the forecast ambient temperature (the rule curve).

    Parameters
    ----------
    sim : FleetSimulator
        Gives the rule curve.
    t_amb_forecast : numpy.ndarray of shape (T+1,)
        Ambient temperature over the horizon. [°C]

    Returns
    -------
    numpy.ndarray of shape (T+1,)
        T_rule(k|t). [°C]
    """
    return np.asarray(sim.rule(np.asarray(t_amb_forecast, dtype=float)), dtype=float)


class _History:
    """A coach's recent samples at the controller's ticks (kept to ρ + 1)."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.times: list[float] = []
        self.y: list[np.ndarray] = []
        self.u: list[float] = []
        self.d: list[np.ndarray] = []

    def add(self, time_s: float, y: np.ndarray, keep: int) -> None:
        self.times.append(time_s)
        self.y.append(y)
        excess = len(self.times) - (keep + 1)
        if excess > 0:
            del self.times[:excess], self.y[:excess]
            del self.u[: max(0, len(self.u) - keep)], self.d[: max(0, len(self.d) - keep)]


def build_controllers(
    kind: str,
    n: int,
    predictor: MultistepPredictor | None = None,
    settings: OCPSettings | None = None,
    *,
    sampling_min: float = 5.0,
) -> list[DDPCController | None]:
    """One controller per coach; the coaches share one coach model.

    Parameters
    ----------
    kind : str
        ``"rule"`` (no controller: T_ref = T_rule), ``"ddpc"`` (needs a predictor) or
        ``"edge"`` (the band-edge reference).
    n : int
        Number of coaches.
    predictor : MultistepPredictor, optional
        The prediction model; for ``"edge"`` it only sets ρ and T (default 12 and 6).
    settings : OCPSettings, optional
        Weights and bounds.
    sampling_min : float, default 5.0
        The controller's period. [min]

    Returns
    -------
    list of DDPCController or None
        ``n`` controllers (``None`` for ``"rule"``).

    Raises
    ------
    ValueError
        For an unknown kind, or ``"ddpc"`` without a predictor.
    """
    if kind == "rule":
        return [None] * n
    model = CoachModel(dt_s=sampling_min * 60.0)
    if kind == "ddpc":
        if predictor is None:
            raise ValueError("the ddpc controller needs a prediction model")
        return [
            DDPCController(predictor, settings, sampling_min=sampling_min, model=model)
            for _ in range(n)
        ]
    if kind == "edge":
        rho = predictor.rho if predictor is not None else RHO
        horizon = predictor.horizon if predictor is not None else HORIZON
        return [
            BandEdgeController(
                settings, sampling_min=sampling_min, rho=rho, horizon=horizon, model=model
            )
            for _ in range(n)
        ]
    raise ValueError(f"unknown controller {kind!r} (rule, ddpc, edge)")


def tick_summary(log: TickLog) -> dict:
    """Summarise a tick log.

    Parameters
    ----------
    log : TickLog
        The ticks.

    Returns
    -------
    dict
        ``ticks`` (count), ``reasons`` (count by reason), ``median_solve_ms`` (over the ticks
        that applied the optimum) and ``median_step_ms`` (ms; None without ticks).
    """
    reasons: dict[str, int] = {}
    for r in log.results:
        reasons[r.reason] = reasons.get(r.reason, 0) + 1
    solved = [r.solve_time_s for r in log.results if r.source == "ddpc"]
    steps = [r.step_time_s for r in log.results]
    return {
        "ticks": len(log.results),
        "reasons": dict(sorted(reasons.items())),
        "median_solve_ms": float(np.median(solved) * 1e3) if solved else None,
        "median_step_ms": float(np.median(steps) * 1e3) if steps else None,
    }
