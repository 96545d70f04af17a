"""The SBB simulator of the paper's Figure 2, for a fleet of half coaches at once.

Rule-based control → HVAC state, substate and PID → heat distribution Λ → coach, closed through
the (noisy, quantised) room-temperature sensors. Every coach is a row of the same arrays, so a
fleet of N coaches costs one set of numpy operations per time step, not N.

Time advances in steps of ``dt_s`` (10 s by default): at each step the HVAC control runs on the
measurements, its heat flows are held (zero-order hold, as a digital controller does) and the nine
temperatures are integrated over the step with RK4 (:func:`trainclimate.sim.thermal.rk4_step`).
Records at index k hold the state at the start of step k and the inputs, heat flows and power over
[t_k, t_k + dt).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from trainclimate.coach.meters import METERS
from trainclimate.coach.rule import MODE_REGULAR, RuleCurve
from trainclimate.coach.states import OFF
from trainclimate.sim import hvac, thermal
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, stack
from trainclimate.sim.power import electrical_power

DECKS = ("up", "mid", "low")
#: A temperature no coach reaches: a state beyond ± this means the integration diverged (caught
#: well before it overflows to inf or NaN). [°C]
RUNAWAY_C = 1000.0


class SimulationError(RuntimeError):
    """The simulation diverged: a temperature is NaN or beyond ±:data:`RUNAWAY_C`, or the
    electrical power is not finite."""


#: The PID memory that a simulator snapshot carries.
_PID_STATE = ("integral", "deriv", "last_y", "output", "last_e", "demand", "cooling_off_s")

#: A setpoint policy: called at every step with the step index and the simulator, returns T_ref
#: (N,) in °C. ``None`` means the rule-based architecture, T_ref = T_rule.
SetpointPolicy = Callable[[int, "FleetSimulator"], np.ndarray]


@dataclass
class SimulationResult:
    """Everything recorded by :class:`FleetSimulator` over S steps for N coaches.

    Index k holds the state at the start of step k and the inputs, heat flows and power over
    [t_k, t_k + dt).

    Attributes
    ----------
    time : pandas.DatetimeIndex
        UTC start of each step, shape (S,).
    dt_s : float
        Step. [s]
    env : Environment
        The environment simulated (it may extend beyond ``time``).
    states_c : numpy.ndarray of shape (S, N, 9)
        True temperatures (:data:`~trainclimate.sim.thermal.STATE_NAMES`). [°C]
    t_room_meas_c : numpy.ndarray of shape (S, N, 3)
        Sensor readings of the deck temperatures. [°C]
    t_ref_c, t_rule_c : numpy.ndarray of shape (S, N)
        Applied setpoint T_ref and rule-based T_rule. [°C]
    hvac_state, substate : numpy.ndarray of int8, shape (S, N)
        HVAC state codes (:mod:`trainclimate.coach.states`) and substate codes
        (:mod:`trainclimate.sim.hvac`).
    fresh_fraction : numpy.ndarray of shape (S, N)
        Fresh-air fraction of the supply air. [–]
    q_hvac_w, q_fw_w : numpy.ndarray of shape (S, N, 3)
        HVAC heat flow (positive heats) and floor/wall heating per deck. [W]
    power_w : dict of str to numpy.ndarray of shape (S, N)
        Electrical power by component: heater, floor_wall, compressor, fans. [W]
    flows_w : numpy.ndarray of shape (S, N, len(FLOW_NAMES)) or None
        Step-mean heat flows, when recorded. [W]
    final_states_c : numpy.ndarray of shape (N, 9)
        Temperatures at the end of the last step. [°C]
    """

    time: pd.DatetimeIndex
    dt_s: float
    env: Environment
    states_c: np.ndarray  # (S, N, 9) true temperatures at the start of each step
    t_room_meas_c: np.ndarray  # (S, N, 3) sensor readings
    t_ref_c: np.ndarray
    t_rule_c: np.ndarray
    hvac_state: np.ndarray
    substate: np.ndarray
    fresh_fraction: np.ndarray
    q_hvac_w: np.ndarray  # (S, N, 3)
    q_fw_w: np.ndarray  # (S, N, 3)
    power_w: dict[str, np.ndarray]  # component → (S, N)
    flows_w: np.ndarray | None  # (S, N, n_flows) step means, when recorded
    final_states_c: np.ndarray  # (N, 9) state at the end of the last step

    @property
    def t_room_c(self) -> np.ndarray:
        """True deck temperatures T_room (up, mid, low), shape (S, N, 3). [°C]"""
        return self.states_c[:, :, thermal.ROOM]

    @property
    def total_power_w(self) -> np.ndarray:
        """Total electrical power of the HVAC, shape (S, N). [W]"""
        return sum(self.power_w.values())

    def meter_w(self, meter: str) -> np.ndarray:
        """The electrical power a meter counts (:data:`~trainclimate.coach.meters.METERS`), shape
        (S, N). [W]"""
        return sum(self.power_w[c] for c in METERS[meter])

    @property
    def energy_kwh(self) -> np.ndarray:
        """Electrical energy of each coach over the run, shape (N,). [kWh]"""
        return self.total_power_w.sum(axis=0) * self.dt_s / 3.6e6

    def frame(self, coach: int = 0) -> pd.DataFrame:
        """The full time series of one coach.

        Parameters
        ----------
        coach : int, default 0
            Coach index.

        Returns
        -------
        pandas.DataFrame
            Indexed by UTC time; units in the column names (``_c`` °C, ``_w`` W, ``_kw`` kW,
            ``_w_m2`` W/m², ``_deg`` °, ``_kmh`` km/h, ``_pct`` % of seats).
        """
        cols: dict[str, np.ndarray] = {}
        for j, name in enumerate(thermal.STATE_NAMES):
            cols[name] = self.states_c[:, coach, j]
        for d, deck in enumerate(DECKS):
            cols[f"t_room_meas_{deck}_c"] = self.t_room_meas_c[:, coach, d]
        env, s = self.env, len(self.time)
        cols.update(
            t_ref_c=self.t_ref_c[:, coach],
            t_rule_c=self.t_rule_c[:, coach],
            t_amb_c=env.t_amb_c[:s, coach],
            ghi_w_m2=env.ghi_w_m2[:s, coach],
            q_gt_w_m2=env.q_roof_w_m2[:s, coach],
            q_gs_w_m2=env.q_side_w_m2[:s, coach],
            solar_zenith_deg=env.zenith_deg[:s, coach],
            solar_azimuth_deg=env.azimuth_deg[:s, coach],
            heading_deg=env.heading_deg[:s, coach],
            speed_kmh=env.speed_kmh[:s, coach],
            occupancy_pct=env.occupancy_pct[:s, coach],
            door_open=env.door_open[:s, coach],
            mode=env.mode[:s, coach],
            hvac_state=self.hvac_state[:, coach],
            substate=self.substate[:, coach],
            fresh_air_fraction=self.fresh_fraction[:, coach],
        )
        for d, deck in enumerate(DECKS):
            cols[f"q_hvac_{deck}_w"] = self.q_hvac_w[:, coach, d]
        for d, deck in enumerate(DECKS):
            cols[f"q_fw_{deck}_w"] = self.q_fw_w[:, coach, d]
        for name, value in self.power_w.items():
            cols[f"power_{name}_kw"] = value[:, coach] / 1e3
        cols["power_kw"] = self.total_power_w[:, coach] / 1e3
        if self.flows_w is not None:
            for j, name in enumerate(thermal.FLOW_NAMES):
                cols[f"q_{name}_w"] = self.flows_w[:, coach, j]
        return pd.DataFrame(cols, index=pd.DatetimeIndex(self.time, name="time"))


def initial_states(env: Environment, rule: RuleCurve) -> np.ndarray:
    """A plausible initial state of every coach.

    A coach already in regular mode starts at T_rule throughout its interior; any other starts
    3 K above ambient (residual warmth); the chassis 1 K above T_amb.

    Parameters
    ----------
    env : Environment
        Its first step's T_amb and mode are used.
    rule : RuleCurve
        The rule-based controller.

    Returns
    -------
    numpy.ndarray of shape (N, 9)
        Temperatures in :data:`~trainclimate.sim.thermal.STATE_NAMES` order. [°C]
    """
    t_amb = env.t_amb_c[0]
    interior = np.where(env.mode[0] == MODE_REGULAR, rule(t_amb), t_amb + 3.0)
    return np.column_stack([interior] * 6 + [t_amb + 1.0] * 3)


class FleetSimulator:
    """N half coaches under the two-level control architecture, stepped together.

    The SBB simulator of Figure 2 [1]_ (see the module docstring). Call :meth:`step` or
    :meth:`run`, then :meth:`result`.

    Parameters
    ----------
    params : CoachParams or list of CoachParams
        One parameter set per coach, or one used for all.
    env : Environment
        The disturbances and operation; its time step is the simulator's.
    rule : RuleCurve, optional
        The rule-based controller (default: :class:`~trainclimate.coach.rule.RuleCurve`).
    seed : int, default 0
        Seed of the sensor noise.
    initial_c : numpy.ndarray of shape (N, 9) or (9,), optional
        Initial temperatures (default: :func:`initial_states`). [°C]
    record_flows : bool, default False
        Keep every heat flow (memory S × N × 36 floats).

    Attributes
    ----------
    T : numpy.ndarray of shape (N, 9)
        Current temperatures. [°C]
    k : int
        Index of the next step.
    hvac_state : numpy.ndarray of int8, shape (N,)
        Current HVAC state.

    Raises
    ------
    ValueError
        If the number of parameter sets does not match the environment's coaches.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II and Figure 2.
    """

    def __init__(
        self,
        params: list[CoachParams] | CoachParams,
        env: Environment,
        *,
        rule: RuleCurve | None = None,
        seed: int = 0,
        initial_c: np.ndarray | None = None,
        record_flows: bool = False,
    ):
        n = env.n_coaches
        if isinstance(params, CoachParams):
            params = [params] * n
        if len(params) != n:
            raise ValueError(f"{len(params)} parameter sets for {n} coaches")
        self.p = stack(list(params))
        self.env = env
        self.rule = rule or RuleCurve()
        self.dt_s = env.dt_s
        self.rng = np.random.default_rng(seed)
        self.inv_cap = 1.0 / thermal.capacities(self.p)
        self.T = (
            np.array(initial_c, dtype=float)
            if initial_c is not None
            else initial_states(env, self.rule)
        )
        self.T = np.broadcast_to(self.T, (n, thermal.N_STATES)).copy()
        self.hvac_state = np.full(n, OFF, dtype=np.int8)
        self.pid = hvac.PID(n, self.p, self.dt_s)
        self.k = 0
        s = len(env.time)
        self._rec = {
            "states_c": np.empty((s, n, thermal.N_STATES)),
            "t_room_meas_c": np.empty((s, n, 3)),
            "t_ref_c": np.empty((s, n)),
            "t_rule_c": np.empty((s, n)),
            "hvac_state": np.empty((s, n), dtype=np.int8),
            "substate": np.empty((s, n), dtype=np.int8),
            "fresh_fraction": np.empty((s, n)),
            "q_hvac_w": np.empty((s, n, 3)),
            "q_fw_w": np.empty((s, n, 3)),
        }
        self._power = {k: np.empty((s, n)) for k in ("heater", "floor_wall", "compressor", "fans")}
        self._flows = np.empty((s, n, len(thermal.FLOW_NAMES))) if record_flows else None

    @property
    def n_steps(self) -> int:
        """Number of steps S of the environment."""
        return len(self.env.time)

    def measure(self) -> np.ndarray:
        """Read the deck temperature sensors: Gaussian noise, then quantisation.

        Draws from the sensor-noise generator (:meth:`noise`).

        Returns
        -------
        numpy.ndarray of shape (N, 3)
            Readings. [°C]
        """
        p = self.p
        noisy = self.T[:, thermal.ROOM] + self.noise() * (p.sensor_noise_k[:, None])
        q = p.sensor_quantum_k[:, None]
        return np.where(q > 0, np.round(noisy / np.where(q > 0, q, 1.0)) * q, noisy)

    def noise(self) -> np.ndarray:
        """One standard normal draw per deck sensor, from the sensor-noise generator.

        Returns
        -------
        numpy.ndarray of shape (N, 3)
        """
        return self.rng.normal(size=(self.T.shape[0], 3))

    def t_rule(self, k: int | None = None) -> np.ndarray:
        """The rule-based setpoint T_rule from the step's ambient temperature.

        Parameters
        ----------
        k : int, optional
            Step index (default: the current step).

        Returns
        -------
        numpy.ndarray of shape (N,)
            T_rule. [°C]
        """
        return self.rule(self.env.t_amb_c[self.k if k is None else k])

    def step(self, t_ref_c: np.ndarray | None = None) -> None:
        """Advance one time step and record it.

        Parameters
        ----------
        t_ref_c : array-like of shape (N,) or float, optional
            Setpoint T_ref; None applies T_rule (the rule-based architecture). [°C]

        Raises
        ------
        IndexError
            If the simulation has reached the end of its environment.
        SimulationError
            If the step left a temperature NaN or beyond ±:data:`RUNAWAY_C`, or its power is not
            finite (e.g. a heat capacity too small for its conductances: RK4 is unstable).
        """
        if self.k >= self.n_steps:
            raise IndexError("the simulation has reached the end of its environment")
        k, env, p = self.k, self.env, self.p
        t_amb = env.t_amb_c[k]
        t_rule = self.rule(t_amb)
        t_ref = (
            t_rule if t_ref_c is None else np.broadcast_to(np.asarray(t_ref_c, float), t_rule.shape)
        )
        y = self.measure()
        passengers = env.occupancy_pct[k][:, None] / 100.0 * p.seats

        new_state = hvac.next_state(
            self.hvac_state, env.mode[k], y, t_ref, t_amb, p, demand_w=self.pid.demand
        )
        self.pid.reset_on_transition(self.hvac_state, new_state)
        self.hvac_state = new_state
        fresh, sub = hvac.fresh_air_fraction(new_state, y, t_ref, t_amb, passengers, p)
        q_hvac = self.pid.update(hvac.pid_setpoint(new_state, t_ref, p), y, new_state)
        q_fw = hvac.floor_wall_heating(new_state, t_amb, p)
        q_in = np.concatenate([q_hvac, q_fw], axis=1)
        q_act = np.einsum("nij,nj->ni", p.distribution, q_in)

        drv = thermal.Drivers(
            q_act_w=q_act,
            t_amb_c=t_amb,
            speed_kmh=env.speed_kmh[k],
            q_roof_w_m2=env.q_roof_w_m2[k],
            q_side_w_m2=env.q_side_w_m2[k],
            passengers=passengers,
            door_open=env.door_open[k],
            fresh_air_kg_s=hvac.fresh_air_mass_flow(fresh, p),
        )
        rec = self._rec
        rec["states_c"][k] = self.T
        rec["t_room_meas_c"][k] = y
        rec["t_ref_c"][k] = t_ref
        rec["t_rule_c"][k] = t_rule
        rec["hvac_state"][k] = new_state
        rec["substate"][k] = sub
        rec["fresh_fraction"][k] = fresh
        rec["q_hvac_w"][k] = q_hvac
        rec["q_fw_w"][k] = q_fw
        # the air entering the evaporator: the fresh share of outside air, the rest return air
        t_mix = fresh * t_amb + (1.0 - fresh) * self.T[:, thermal.ROOM].mean(axis=1)
        power = electrical_power(q_hvac, q_fw, t_amb, hvac.fans_running(new_state), p, t_mix)
        self._power["heater"][k] = power.heater_w
        self._power["floor_wall"][k] = power.floor_wall_w
        self._power["compressor"][k] = power.compressor_w
        self._power["fans"][k] = power.fans_w

        self.T, flows = thermal.rk4_step(self.T, drv, p, self.inv_cap, self.dt_s)
        diverged = ~np.all(np.abs(self.T) < RUNAWAY_C, axis=1) | ~np.isfinite(power.total_w)
        if diverged.any():
            raise SimulationError(
                f"the simulation diverged in step {k} ({env.time[k]:%Y-%m-%d %H:%M} UTC), coach "
                f"{int(np.argmax(diverged))}: a temperature is NaN or beyond ±{RUNAWAY_C:g} °C, "
                "or the power is not finite; check the coach parameters (a heat capacity too "
                f"small for its conductances makes the {self.dt_s:g} s step unstable)"
            )
        if self._flows is not None:
            self._flows[k] = flows
        self.k += 1

    def run(self, policy: SetpointPolicy | None = None, steps: int | None = None) -> None:
        """Advance several steps.

        Parameters
        ----------
        policy : SetpointPolicy, optional
            Called at every step with the step index and the simulator, returns T_ref (N,) in
            °C; None applies T_rule.
        steps : int, optional
            Number of steps (default: to the end of the environment).
        """
        end = self.n_steps if steps is None else min(self.n_steps, self.k + steps)
        while self.k < end:
            self.step(None if policy is None else policy(self.k, self))

    def snapshot(self) -> dict:
        """The state that carries from one step to the next, as JSON-ready plain data.

        Returns
        -------
        dict
            ``T`` (temperatures, °C), ``hvac_state``, ``pid`` (every PID's memory, NaN as None)
            and ``rng`` (the sensor-noise generator's state).
        """
        pid = {
            name: [
                [float(v) if np.isfinite(v) else None for v in row]
                for row in getattr(self.pid, name)
            ]
            for name in _PID_STATE
        }
        return {
            "T": self.T.tolist(),
            "hvac_state": self.hvac_state.astype(int).tolist(),
            "pid": pid,
            "rng": self.rng.bit_generator.state,
        }

    def restore(self, state: dict) -> None:
        """Continue from a :meth:`snapshot`.

        Parameters
        ----------
        state : dict
            A snapshot of a simulator with as many coaches.

        Raises
        ------
        ValueError
            If the snapshot is of a different number of coaches.
        """
        T = np.asarray(state["T"], dtype=float)
        if T.shape != self.T.shape:
            raise ValueError(f"snapshot of {T.shape[0]} coaches for {self.T.shape[0]}")
        self.T = T
        self.hvac_state = np.asarray(state["hvac_state"], dtype=np.int8)
        for name in _PID_STATE:
            rows = state["pid"].get(name)
            if rows is None:  # a snapshot from before this memory existed: its initial value
                continue
            setattr(
                self.pid, name, np.array([[np.nan if v is None else v for v in r] for r in rows])
            )
        self.rng.bit_generator.state = state["rng"]

    def result(self) -> SimulationResult:
        """What has been simulated so far.

        Returns
        -------
        SimulationResult
            The first :attr:`k` steps.
        """
        k = self.k
        rec = {name: arr[:k] for name, arr in self._rec.items()}
        return SimulationResult(
            time=self.env.time[:k],
            dt_s=self.dt_s,
            env=self.env,
            power_w={name: arr[:k] for name, arr in self._power.items()},
            flows_w=None if self._flows is None else self._flows[:k],
            final_states_c=self.T.copy(),
            **rec,
        )
