"""The HVAC system and control block (paper, Section II.B), vectorised over coaches.

Every function takes *stacked* parameters (:func:`trainclimate.sim.params.stack`): each field has
a leading coach axis N.

Three sub-blocks, as in the paper's Figure 2:

- :func:`next_state`: the HVAC state from the mode, T_room, T_ref and T_amb, with hysteresis.
  Regular mode: preheating, precooling, heating, cooling, mixed. Slumber mode: active heating,
  active ventilation, active cooling, off. Off mode: off. The states' codes and names are the
  coach's vocabulary (:mod:`trainclimate.coach.states`).
- :func:`fresh_air_fraction`: the substate — recirculated, outside or mixed air — from the
  state, T_room, T_amb and the occupancy (a minimum of fresh air per passenger).
- :class:`PID`: one PID per deck whose output limits, rate limits, initial conditions, resets and
  anti-windup are set by the state.

Plus the floor and wall heating (:func:`floor_wall_heating`): maximum in preheating, piecewise
linear in T_amb in heating, off otherwise.
"""

from __future__ import annotations

import numpy as np

from trainclimate.coach.rule import MODE_REGULAR, MODE_SLUMBER
from trainclimate.coach.states import (
    COOLING,
    HEATING,
    MIXED,
    OFF,
    PRECOOLING,
    PREHEATING,
    SLUMBER_COOLING,
    SLUMBER_HEATING,
    SLUMBER_OFF,
    SLUMBER_VENTILATION,
)
from trainclimate.sim.params import AIR_DENSITY_KG_M3, CoachParams

# Substates (fresh-air modes) -----------------------------------------------------------------
RECIRCULATED, OUTSIDE, MIXED_AIR = 0, 1, 2
SUBSTATE_NAMES = {RECIRCULATED: "recirculated", OUTSIDE: "outside", MIXED_AIR: "mixed"}


def first_true(conditions, choices, default):
    """Pick, element-wise, the choice of the first true condition (like :func:`numpy.select`).

    A chain of :func:`numpy.where`, several times faster than :func:`numpy.select` on the small
    arrays of one time step.

    Parameters
    ----------
    conditions : sequence of array-like of bool
        Conditions, in priority order, broadcastable against each other.
    choices : sequence of array-like or scalar
        One value per condition.
    default : array-like or scalar
        The value where no condition holds.

    Returns
    -------
    numpy.ndarray
        The broadcast shape of conditions, choices and default.
    """
    out = default
    for cond, choice in zip(reversed(conditions), reversed(choices), strict=True):
        out = np.where(cond, choice, out)
    return out


def interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Row-wise piecewise-linear interpolation, held constant outside the breakpoints.

    Parameters
    ----------
    x : numpy.ndarray of shape (N,)
        Where to interpolate, one point per row.
    xp : numpy.ndarray of shape (N, k)
        Breakpoints, each row increasing.
    fp : numpy.ndarray of shape (N, k)
        Values at the breakpoints.

    Returns
    -------
    numpy.ndarray of shape (N,)
        The interpolated value of each row.
    """
    out = np.where(x <= xp[:, 0], fp[:, 0], fp[:, -1])
    for j in range(xp.shape[1] - 1):
        x0, x1, f0, f1 = xp[:, j], xp[:, j + 1], fp[:, j], fp[:, j + 1]
        inside = (x > x0) & (x <= x1)
        out = np.where(inside, f0 + (f1 - f0) * (x - x0) / (x1 - x0), out)
    return out


def _climate_state(state, t_amb, t_ref, p: CoachParams) -> np.ndarray:
    """Heating / cooling / mixed from T_amb against thresholds below T_ref, with hysteresis."""
    heat_th = t_ref - p.heat_below_k
    cool_th = t_ref - p.cool_above_k
    hy = p.climate_hysteresis_k
    fresh = first_true([t_amb < heat_th, t_amb > cool_th], [HEATING, COOLING], MIXED)
    from_mixed = first_true([t_amb < heat_th - hy, t_amb > cool_th + hy], [HEATING, COOLING], MIXED)
    from_heating = np.where(
        t_amb > heat_th + hy, np.where(t_amb > cool_th + hy, COOLING, MIXED), HEATING
    )
    from_cooling = np.where(
        t_amb < cool_th - hy, np.where(t_amb < heat_th - hy, HEATING, MIXED), COOLING
    )
    return first_true(
        [state == HEATING, state == COOLING, state == MIXED],
        [from_heating, from_cooling, from_mixed],
        fresh,
    )


def _room_state(state, t_room_c, t_ref_c, demand_w, p: CoachParams) -> np.ndarray:
    """Between the ambient thresholds: the state the decks ask for (``climate_from_room``).

    From mixed, cooling once no deck's demand heats, one cools and none is colder than T_ref by
    half of ``climate_room_band_k``, heating likewise; from cooling (heating), back to mixed once
    a deck is ``climate_room_band_k`` colder (warmer) than T_ref — it needs what the state
    forbids.
    """
    cooling, heating = demand_w < 0, demand_w > 0
    band = p.climate_room_band_k
    error = t_room_c.mean(axis=1) - t_ref_c
    too_cold, too_warm = error < -band, error > band
    # back from mixed only with the coach within half the band on the side the state cannot
    # correct: the hysteresis that lets the decks' demand change sign first
    cool = cooling.any(axis=1) & ~heating.any(axis=1) & (error >= -band / 2)
    heat = heating.any(axis=1) & ~cooling.any(axis=1) & (error <= band / 2)
    from_mixed = first_true([cool, heat], [COOLING, HEATING], MIXED)
    return first_true(
        [state == COOLING, state == HEATING],
        [np.where(too_cold, MIXED, COOLING), np.where(too_warm, MIXED, HEATING)],
        from_mixed,
    )


def next_state(
    state: np.ndarray,
    mode: np.ndarray,
    t_room_c: np.ndarray,
    t_ref_c: np.ndarray,
    t_amb_c: np.ndarray,
    p: CoachParams,
    demand_w: np.ndarray | None = None,
) -> np.ndarray:
    """The HVAC state block: the HVAC state after this control step.

    Regular mode: preheating while T_room < T_ref − ``pre_enter_k`` until it reaches
    T_ref − ``pre_exit_k`` (likewise precooling above); otherwise heating below
    T_amb = T_ref − ``heat_below_k``, cooling above T_ref − ``cool_above_k``, each switch with
    ``climate_hysteresis_k``; between, with ``climate_from_room`` and the decks' demand, the
    state the decks ask for (cooling while no deck heats, heating while none cools, mixed when
    they pull both ways or the coach's mean has drifted ``climate_room_band_k`` past T_ref),
    else mixed. Slumber mode keeps a wide band: active heating below T_ref − ``slumber_enter_k``
    until T_ref − ``slumber_exit_k``, active cooling likewise above, active ventilation when the
    coach is warm and outside air is cooler, off otherwise. Off mode: off.

    Parameters
    ----------
    state : numpy.ndarray of shape (N,)
        The previous HVAC state (``OFF``, ``PREHEATING``, …).
    mode : numpy.ndarray of shape (N,)
        HVAC mode, ``MODE_*`` of :mod:`trainclimate.coach.rule`.
    t_room_c : numpy.ndarray of shape (N, 3)
        Measured deck temperatures; the unit controls on their mean. [°C]
    t_ref_c : numpy.ndarray of shape (N,)
        Setpoint T_ref. [°C]
    t_amb_c : numpy.ndarray of shape (N,)
        Ambient temperature. [°C]
    p : CoachParams
        Parameters stacked over the N coaches.
    demand_w : numpy.ndarray of shape (N, 3), optional
        Each deck's sustained demand, its PID's output averaged over the integral time
        (:attr:`PID.demand`; positive heats); without it the ambient alone decides between the
        thresholds. [W]

    Returns
    -------
    numpy.ndarray of int, shape (N,)
        The new HVAC state.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.B.
    """
    t_avg = t_room_c.mean(axis=1)
    dev = t_avg - t_ref_c

    # regular mode
    climate = _climate_state(state, t_amb_c, t_ref_c, p)
    if demand_w is not None:
        room = _room_state(state, t_room_c, t_ref_c, demand_w, p)
        climate = np.where((climate == MIXED) & (p.climate_from_room > 0), room, climate)
    stay_pre = (state == PREHEATING) & (dev < -p.pre_exit_k)
    stay_precool = (state == PRECOOLING) & (dev > p.pre_exit_k)
    regular = first_true(
        [dev < -p.pre_enter_k, dev > p.pre_enter_k, stay_pre, stay_precool],
        [PREHEATING, PRECOOLING, PREHEATING, PRECOOLING],
        climate,
    )

    # slumber mode
    heat_on, heat_off = dev < -p.slumber_enter_k, dev >= -p.slumber_exit_k
    cool_on, cool_off = dev > p.slumber_enter_k, dev <= p.slumber_exit_k
    vent_on = (dev > p.slumber_vent_k) & (t_amb_c < t_avg - p.slumber_vent_k)
    vent_off = (dev <= p.slumber_vent_k - 1.0) | (t_amb_c >= t_avg - 1.0)
    idle = first_true(
        [heat_on, cool_on, vent_on],
        [SLUMBER_HEATING, SLUMBER_COOLING, SLUMBER_VENTILATION],
        SLUMBER_OFF,
    )
    slumber = first_true(
        [
            (state == SLUMBER_HEATING) & ~heat_off,
            (state == SLUMBER_COOLING) & ~cool_off,
            (state == SLUMBER_VENTILATION) & cool_on,
            (state == SLUMBER_VENTILATION) & ~vent_off,
        ],
        [SLUMBER_HEATING, SLUMBER_COOLING, SLUMBER_COOLING, SLUMBER_VENTILATION],
        idle,
    )
    return first_true([mode == MODE_REGULAR, mode == MODE_SLUMBER], [regular, slumber], OFF)


def minimum_fresh_fraction(passengers: np.ndarray, p: CoachParams, base: bool) -> np.ndarray:
    """Minimum fresh-air fraction of the supply air: per passenger, plus a base if asked.

    Per passenger ``fresh_air_per_passenger_m3_h`` (20 m³/h, the order of EN 14750-1's
    requirement); the base share ``fresh_air_base_fraction`` keeps the car body over-pressured.

    Parameters
    ----------
    passengers : numpy.ndarray of shape (N, 3)
        Passengers per deck.
    p : CoachParams
        Parameters stacked over the N coaches.
    base : bool
        Whether to add the base share.

    Returns
    -------
    numpy.ndarray of shape (N,)
        The fraction, clipped to [0, 1]. [–]
    """
    f = passengers.sum(axis=1) * p.fresh_air_per_passenger_m3_h / p.supply_air_m3_h
    if base:
        f = f + p.fresh_air_base_fraction
    return np.clip(f, 0.0, 1.0)


def fresh_air_fraction(
    state: np.ndarray,
    t_room_c: np.ndarray,
    t_ref_c: np.ndarray,
    t_amb_c: np.ndarray,
    passengers: np.ndarray,
    p: CoachParams,
) -> tuple[np.ndarray, np.ndarray]:
    """The HVAC substate block: the fresh-air fraction of the supply air and its label.

    - off / slumber off: fans stopped, f = 0;
    - preheating / precooling: recirculated air, only the per-passenger minimum;
    - heating: recirculated (base + per-passenger minimum), or all outside air when outside is
      warmer than the coach by ``economiser_band_k``;
    - cooling: recirculated, or — when outside is cooler by ``economiser_band_k`` — an economiser
      damper opening linearly from the minimum at T_ref − 0.5 K to all outside air at
      T_ref + 0.5 K (mixed air between);
    - mixed state: as heating at or below T_ref; above it the economiser damper opens from the
      minimum at T_ref to all outside air at T_ref + 1 K (continuous at T_ref: the heaters may
      still run in the mixed state, and free cooling must not fight them);
    - slumber ventilation: all outside air; slumber heating / cooling: the minimum.

    Parameters
    ----------
    state : numpy.ndarray of shape (N,)
        The HVAC state (after :func:`next_state`).
    t_room_c, t_ref_c, t_amb_c : numpy.ndarray
        As in :func:`next_state` (°C); the mean of ``t_room_c`` is compared with T_amb.
    passengers : numpy.ndarray of shape (N, 3)
        Passengers per deck.
    p : CoachParams
        Parameters stacked over the N coaches.

    Returns
    -------
    fraction : numpy.ndarray of shape (N,)
        Fresh-air fraction f ∈ [0, 1] of the supply air. [–]
    label : numpy.ndarray of shape (N,)
        ``RECIRCULATED``, ``OUTSIDE`` or ``MIXED_AIR``.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.B.
    """
    t_avg = t_room_c.mean(axis=1)
    f_min = minimum_fresh_fraction(passengers, p, base=True)
    f_pax = minimum_fresh_fraction(passengers, p, base=False)
    band = p.economiser_band_k
    heat_f = np.where(t_amb_c > t_avg + band, 1.0, f_min)
    economiser = t_amb_c < t_avg - band
    opening = np.clip(t_avg - (t_ref_c - 0.5), 0.0, 1.0)
    cool_f = np.where(economiser, f_min + (1.0 - f_min) * opening, f_min)
    # in the mixed state the heaters may still run: the damper opens only above T_ref (closed at
    # T_ref, fully open at T_ref + 1 K), so free cooling never fights the heating
    mixed_opening = np.clip(t_avg - t_ref_c, 0.0, 1.0)
    mixed_cool_f = np.where(economiser, f_min + (1.0 - f_min) * mixed_opening, f_min)
    f = first_true(
        [
            (state == OFF) | (state == SLUMBER_OFF),
            (state == PREHEATING) | (state == PRECOOLING),
            state == HEATING,
            state == COOLING,
            state == MIXED,
            state == SLUMBER_VENTILATION,
        ],
        [0.0, f_pax, heat_f, cool_f, np.where(t_avg > t_ref_c, mixed_cool_f, heat_f), 1.0],
        f_min,
    )
    label = first_true([f >= 1.0 - 1e-9, f <= f_min + 1e-9], [OUTSIDE, RECIRCULATED], MIXED_AIR)
    return f, label


def fresh_air_mass_flow(fraction: np.ndarray, p: CoachParams) -> np.ndarray:
    """Outside air supplied to each deck.

    Parameters
    ----------
    fraction : numpy.ndarray of shape (N,)
        Fresh-air fraction of the supply air. [–]
    p : CoachParams
        Parameters stacked over the N coaches.

    Returns
    -------
    numpy.ndarray of shape (N, 3)
        Outside-air mass flow into each deck, split by ``air_share``. [kg/s]
    """
    supply_kg_s = p.supply_air_m3_h / 3600.0 * AIR_DENSITY_KG_M3
    return (fraction * supply_kg_s)[:, None] * p.air_share


def fans_running(state: np.ndarray) -> np.ndarray:
    """Whether the supply fans run: in every HVAC state but off and slumber off.

    Parameters
    ----------
    state : numpy.ndarray of shape (N,)
        The HVAC state.

    Returns
    -------
    numpy.ndarray of bool, shape (N,)
    """
    return (state != OFF) & (state != SLUMBER_OFF)


def floor_wall_heating(state: np.ndarray, t_amb_c: np.ndarray, p: CoachParams) -> np.ndarray:
    """Floor and wall heating per deck, Q_fw.

    Maximum in preheating; ``q_fw_max_w`` × a piecewise-linear fraction of T_amb in heating
    (``fw_curve_*``); zero in every other state.

    Parameters
    ----------
    state, t_amb_c, p
        The HVAC state, the ambient temperature (°C) and the parameters, as in
        :func:`next_state`.

    Returns
    -------
    numpy.ndarray of shape (N, 3)
        Heat flow per deck (up, mid, low). [W]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.B.
    """
    frac = interp_rows(t_amb_c, p.fw_curve_t_amb_c, p.fw_curve_fraction)
    level = first_true([state == PREHEATING, state == HEATING], [1.0, frac], 0.0)
    return level[:, None] * p.q_fw_max_w


def output_limits(state: np.ndarray, p: CoachParams) -> tuple[np.ndarray, np.ndarray]:
    """PID output limits per deck set by the HVAC state.

    Heating states allow up to ``q_heat_max_w``, cooling states down to −``q_cool_max_w``, the
    mixed state both, slumber heating/cooling ``slumber_capacity`` of them, other states zero.

    Parameters
    ----------
    state : numpy.ndarray of shape (N,)
        The HVAC state.
    p : CoachParams
        Parameters stacked over the N coaches.

    Returns
    -------
    lo, hi : numpy.ndarray of shape (N, 3)
        Lower (cooling, ≤ 0) and upper (heating, ≥ 0) limit of each deck's output. [W]
    """
    qh, qc = p.q_heat_max_w, p.q_cool_max_w
    cap = p.slumber_capacity[:, None]
    s = state[:, None]
    zero = np.zeros_like(qh)
    lo = first_true(
        [(s == PRECOOLING) | (s == COOLING) | (s == MIXED), s == SLUMBER_COOLING],
        [-qc, -cap * qc],
        zero,
    )
    hi = first_true(
        [(s == PREHEATING) | (s == HEATING) | (s == MIXED), s == SLUMBER_HEATING],
        [qh, cap * qh],
        zero,
    )
    return lo, hi


def pid_setpoint(state: np.ndarray, t_ref_c: np.ndarray, p: CoachParams) -> np.ndarray:
    """The temperature each deck's PID tracks: T_ref, or the slumber band's edge.

    In slumber heating the PID heats to 0.5 K past the exit threshold, T_ref − slumber_exit_k
    + 0.5, so the state machine leaves active heating; slumber cooling mirrors it.

    Parameters
    ----------
    state : numpy.ndarray of shape (N,)
        The HVAC state.
    t_ref_c, p
        Setpoint T_ref (°C) and the parameters, as in :func:`next_state`.

    Returns
    -------
    numpy.ndarray of shape (N,)
        The PID setpoint. [°C]
    """
    back = p.slumber_exit_k - 0.5
    return first_true(
        [state == SLUMBER_HEATING, state == SLUMBER_COOLING],
        [t_ref_c - back, t_ref_c + back],
        t_ref_c,
    )


class PID:
    """The PID sub-block: three PIDs per coach (decks up, mid, low), ``Q = kp·(e + ∫e/ti + td·ė)``.

    State per coach and deck: the integral term (W), the filtered derivative term (W), the last
    measurement (°C), error (K) and output (W). Discrete at the control step ``dt_s``:

    - derivative on the measurement (no kick on setpoint changes), first-order filtered with
      time constant ``td / 8``;
    - output limits from the HVAC state (:func:`output_limits`) and a rate limit
      ``pid_rate_w_s``; the limits win over the rate limit (a heater may always switch off);
    - anti-windup by conditional integration: the integral does not grow while the output is
      held by a limit (output or rate) in the direction the error pushes;
    - reset and initial conditions on a state change: preheating / precooling start at full
      output, slumber heating / cooling and the idle states from zero, and a change among
      heating, cooling and mixed is bumpless (the integral takes the clipped last output);
    - with ``cooling_min_off_s``, a deck's cooling that stopped may not run again before that
      long (its lower output limit is 0 meanwhile).

    Parameters
    ----------
    n : int
        Number of coaches N.
    p : CoachParams
        Parameters stacked over the N coaches.
    dt_s : float
        Control step. [s]

    Attributes
    ----------
    integral : numpy.ndarray of shape (N, 3)
        Integral term. [W]
    deriv : numpy.ndarray of shape (N, 3)
        Filtered derivative term. [W]
    last_y : numpy.ndarray of shape (N, 3)
        Last measurement, NaN before the first update. [°C]
    last_e : numpy.ndarray of shape (N, 3)
        Last error, setpoint − measurement. [K]
    output : numpy.ndarray of shape (N, 3)
        Last output. [W]
    demand : numpy.ndarray of shape (N, 3)
        The output averaged over the integral time (first-order, time constant ``pid_ti_s``):
        the deck's sustained demand, which the state block reads. [W]
    cooling_off_s : numpy.ndarray of shape (N, 3)
        Time since each deck's cooling last ran (inf or NaN: never), for
        ``cooling_min_off_s``. [s]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.B.
    """

    def __init__(self, n: int, p: CoachParams, dt_s: float):
        self.p = p
        self.dt_s = float(dt_s)
        self.integral = np.zeros((n, 3))
        self.deriv = np.zeros((n, 3))
        self.last_y = np.full((n, 3), np.nan)
        self.output = np.zeros((n, 3))
        self.last_e = np.zeros((n, 3))
        self.demand = np.zeros((n, 3))
        self.cooling_off_s = np.full((n, 3), np.inf)

    def reset_on_transition(self, old: np.ndarray, new: np.ndarray) -> None:
        """Apply the state-dependent reset and initial conditions where the state changed.

        Parameters
        ----------
        old, new : numpy.ndarray of shape (N,)
            HVAC state before and after :func:`next_state`.
        """
        changed = old != new
        if not np.any(changed):
            return
        lo, hi = output_limits(new, self.p)
        smooth = (HEATING, COOLING, MIXED)
        bumpless = (np.isin(new, smooth) & np.isin(old, smooth))[:, None]
        # bumpless: the integral absorbs the difference so that P + I + D keeps the last output
        held = np.clip(self.output, lo, hi) - self.p.pid_kp_w_k * self.last_e - self.deriv
        init = first_true(
            [new[:, None] == PREHEATING, new[:, None] == PRECOOLING, bumpless],
            [hi, lo, held],
            0.0,
        )
        c = changed[:, None]
        self.integral = np.where(c, init, self.integral)
        self.deriv = np.where(c & ~bumpless, 0.0, self.deriv)
        self.output = np.where(c, np.clip(self.output, lo, hi), self.output)

    def update(self, setpoint_c: np.ndarray, y_c: np.ndarray, state: np.ndarray) -> np.ndarray:
        """Advance the PIDs by one control step.

        Parameters
        ----------
        setpoint_c : numpy.ndarray of shape (N,)
            Temperature to track (:func:`pid_setpoint`). [°C]
        y_c : numpy.ndarray of shape (N, 3)
            Measured deck temperatures. [°C]
        state : numpy.ndarray of shape (N,)
            The HVAC state, which sets the output limits.

        Returns
        -------
        numpy.ndarray of shape (N, 3)
            HVAC heat flow Q_hvac per deck; positive heats, negative cools. [W]
        """
        p, dt = self.p, self.dt_s
        kp, ti, td, rate = p.pid_kp_w_k, p.pid_ti_s, p.pid_td_s, p.pid_rate_w_s
        e = setpoint_c[:, None] - y_c
        dy = np.where(np.isnan(self.last_y), 0.0, y_c - self.last_y)
        tf = td / 8.0
        self.deriv = (tf * self.deriv - kp * td * dy) / (tf + dt)
        candidate = self.integral + kp * dt / ti * e
        unsat = kp * e + candidate + self.deriv
        lo, hi = output_limits(state, p)
        locked = (self.output >= 0) & (self.cooling_off_s < p.cooling_min_off_s[:, None])
        lo = np.where(locked, np.maximum(lo, 0.0), lo)
        limited = np.clip(unsat, self.output - rate * dt, self.output + rate * dt)
        out = np.clip(limited, lo, hi)
        held = ((out < unsat - 1e-9) & (e > 0)) | ((out > unsat + 1e-9) & (e < 0))
        self.integral = np.clip(np.where(held, self.integral, candidate), lo, hi)
        self.last_y = y_c.copy()
        self.last_e = e
        self.output = out
        self.cooling_off_s = np.where(out < 0, 0.0, self.cooling_off_s + dt)
        self.demand += (out - self.demand) * dt / (ti + dt)
        return out
