"""The controller's model of a coach: the simulator's thermal block, linear and in discrete time.

The coach block of :mod:`trainclimate.sim.thermal` (the paper's Eq. (1) with every heat flow) is
affine in the nine temperatures for a given train speed V, except the ground radiation (T⁴ above
20 °C). So, over a step of Δt with the drivers held,

    x(k+1) = A_d(V) x(k) + B_d(V) [T_amb; q(k)]

with x = [T_room; T_inv; T_chassis] (°C) and q the external heat into each of the nine nodes (W):
solar gains, passengers, ground radiation, and whatever enters the rooms unmeasured (the HVAC's
heating and cooling, extra outside air, the doors). In regular mode the HVAC always supplies the
minimum of fresh air — the base share plus 20 m³/h per passenger
(:func:`~trainclimate.sim.hvac.minimum_fresh_fraction`) — so the model ventilates at that minimum.
A_c and the T_amb column are read off the simulator's own
:func:`~trainclimate.sim.thermal.derivative` (exact: it is affine), and the step is discretised
exactly (zero-order hold) with the matrix exponential of the augmented system. The outer
convection depends on the speed V and the ventilation on the occupancy P, so the model is
tabulated on a grid of both and the nearest point is used.
The ground radiation is evaluated at the current state and held over the step.

This model serves the open-loop prediction of T_opt (HVAC off, paper Section III.C) and the state
estimator of the unmeasured inventory and chassis temperatures (:mod:`.estimator`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from trainclimate.sim import hvac, thermal
from trainclimate.sim.params import STEFAN_BOLTZMANN, CoachParams, stack

N = thermal.N_STATES
#: Train speeds (km/h) and occupancies (% of seats) at which the discrete model is tabulated.
SPEED_GRID_KMH = np.array([0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0])
OCCUPANCY_GRID_PCT = np.array([0.0, 10.0, 25.0, 50.0, 75.0, 100.0, 150.0])


def _drivers(p: CoachParams, t_amb: float, speed: float, **kw) -> thermal.Drivers:
    """Drivers of one coach; ``fresh`` the fresh-air fraction of the supply air (default 0)."""
    one = np.ones(1)
    return thermal.Drivers(
        q_act_w=kw.get("q_act", np.zeros((1, 6))),
        t_amb_c=one * t_amb,
        speed_kmh=one * speed,
        q_roof_w_m2=one * kw.get("q_roof", 0.0),
        q_side_w_m2=one * kw.get("q_side", 0.0),
        passengers=kw.get("passengers", np.zeros((1, 3))),
        door_open=np.zeros(1),
        fresh_air_kg_s=hvac.fresh_air_mass_flow(np.array([kw.get("fresh", 0.0)]), p),
    )


class CoachModel:
    """The discrete linear coach model for one parameter set and step (see the module docstring).

    Parameters
    ----------
    params : CoachParams, optional
        One coach's parameters (default: the fleet's default coach — the controller does not
        know each coach's own).
    dt_s : float, default 300.0
        The step Δt. [s]

    Attributes
    ----------
    A_d : numpy.ndarray of shape (G, 9, 9)
        A_d(V, P) on the G points of the speed × occupancy grid.
    B_d : numpy.ndarray of shape (G, 9, 10)
        B_d(V, P): column 0 multiplies T_amb (°C), columns 1–9 the heat into each node (W).
    S : numpy.ndarray of shape (9, 3)
        Heat into each node (W) per unit of [Q_Gt (W/m²), Q_Gs (W/m²), P (%)].

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.C, Eq. (1).
    """

    def __init__(self, params: CoachParams | None = None, dt_s: float = 300.0):
        self.params = params or CoachParams()
        self.p = stack([self.params])
        self.dt_s = float(dt_s)
        self.inv_cap = 1.0 / thermal.capacities(self.p)[0]
        self.S = self._gain_map()
        grid = [(v, occ) for v in SPEED_GRID_KMH for occ in OCCUPANCY_GRID_PCT]
        self.A_d = np.empty((len(grid), N, N))
        self.B_d = np.empty((len(grid), N, 1 + N))
        for i, (speed, occupancy) in enumerate(grid):
            A_c, b_amb = self.continuous(speed, occupancy)
            M = np.zeros((2 * N + 1, 2 * N + 1))
            M[:N, :N] = A_c
            M[:N, N] = b_amb
            M[:N, N + 1 :] = np.diag(self.inv_cap)
            E = sla.expm(M * self.dt_s)
            self.A_d[i], self.B_d[i] = E[:N, :N], E[:N, N:]

    def continuous(self, speed_kmh: float, occupancy_pct: float = 0.0):
        """The continuous-time model dx/dt = A_c x + b_amb T_amb + C⁻¹ q, read off the simulator.

        With the minimum fresh air for the occupancy P and the HVAC off.

        Parameters
        ----------
        speed_kmh : float
            Train speed V. [km/h]
        occupancy_pct : float, default 0.0
            Occupancy P. [% of seats]

        Returns
        -------
        A_c : numpy.ndarray of shape (9, 9)
            [1/s]
        b_amb : numpy.ndarray of shape (9,)
            [1/s]
        """
        p, inv = self.p, self.inv_cap[None, :]
        passengers = occupancy_pct / 100.0 * p.seats
        fresh = float(hvac.minimum_fresh_fraction(passengers, p, base=True)[0])

        def f(x: np.ndarray, t_amb: float) -> np.ndarray:
            drv = _drivers(p, t_amb, speed_kmh, fresh=fresh)
            return thermal.derivative(x[None, :], drv, p, inv)[0]

        f0 = f(np.zeros(N), 0.0)
        A_c = np.column_stack([f(np.eye(N)[j], 0.0) - f0 for j in range(N)])
        b_amb = f(np.zeros(N), 1.0) - f0
        return A_c, b_amb

    def grid_index(self, d: np.ndarray) -> int:
        """Index of the tabulated model nearest to a disturbance sample's speed and occupancy.

        Parameters
        ----------
        d : numpy.ndarray of shape (5,)
            [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h].

        Returns
        -------
        int
            Index into :attr:`A_d` and :attr:`B_d`.
        """
        i = int(np.argmin(np.abs(SPEED_GRID_KMH - abs(float(d[4])))))
        j = int(np.argmin(np.abs(OCCUPANCY_GRID_PCT - max(float(d[3]), 0.0))))
        return i * len(OCCUPANCY_GRID_PCT) + j

    def _gain_map(self) -> np.ndarray:
        """S (9 × 3): heat into each node (W) per unit of [Q_Gt (W/m²), Q_Gs (W/m²), P (%)] —
        solar on the roof, walls and windows, 100 W per passenger — read off the simulator."""
        p = self.p
        base = thermal.held_flows(_drivers(p, 0.0, 0.0), p) @ thermal.INCIDENCE
        cols = []
        for kw in ({"q_roof": 1.0}, {"q_side": 1.0}, {"passengers": p.seats / 100.0}):
            cols.append((thermal.held_flows(_drivers(p, 0.0, 0.0, **kw), p) @ thermal.INCIDENCE)[0])
        return np.column_stack(cols) - base[0][:, None]

    def ground_w(self, x: np.ndarray, t_amb_c: float) -> float:
        """Ground radiation into the lower chassis at state x, zero at or below the threshold.

        Parameters
        ----------
        x : numpy.ndarray of shape (9,)
            Temperatures; x[8] is the lower chassis. [°C]
        t_amb_c : float
            Ambient temperature. [°C]

        Returns
        -------
        float
            Heat flow. [W]

        References
        ----------
        .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
           Energy Management, Section II.C.5.
        """
        p = self.params
        if t_amb_c <= p.ground_threshold_c:
            return 0.0
        t_g = float(thermal.ground_temperature_c(np.array(t_amb_c), p)) + thermal.KELVIN
        t_c = x[8] + thermal.KELVIN
        return p.ground_emissivity * STEFAN_BOLTZMANN * p.ground_area_m2 * (t_g**4 - t_c**4)

    def known_heat_w(self, x: np.ndarray, d: np.ndarray) -> np.ndarray:
        """External heat into each node: solar gains, passengers and ground radiation.

        Parameters
        ----------
        x : numpy.ndarray of shape (9,)
            Temperatures. [°C]
        d : numpy.ndarray of shape (5,)
            [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h].

        Returns
        -------
        numpy.ndarray of shape (9,)
            Heat into each node. [W]
        """
        q = self.S @ np.asarray(d[1:4], dtype=float)
        q[8] += self.ground_w(x, float(d[0]))
        return q

    def step(self, x: np.ndarray, d: np.ndarray, q_extra_w: np.ndarray | None = None) -> np.ndarray:
        """Advance the state one step, x(k+1) = A_d x(k) + B_d [T_amb; q(k)].

        Parameters
        ----------
        x : numpy.ndarray of shape (9,)
            Temperatures. [°C]
        d : numpy.ndarray of shape (5,)
            [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h], held over the step.
        q_extra_w : numpy.ndarray of shape (9,), optional
            Unmeasured heat into the nodes (e.g. the HVAC's). [W]

        Returns
        -------
        numpy.ndarray of shape (9,)
            Temperatures one step later. [°C]
        """
        i = self.grid_index(d)
        q = self.known_heat_w(x, d)
        if q_extra_w is not None:
            q = q + q_extra_w
        return self.A_d[i] @ x + self.B_d[i, :, 0] * d[0] + self.B_d[i, :, 1:] @ q

    def free_run(self, x0: np.ndarray, d_seq: np.ndarray) -> np.ndarray:
        """Run the model open loop with the HVAC off (as for T_opt, Section III.C).

        Parameters
        ----------
        x0 : numpy.ndarray of shape (9,)
            Initial temperatures. [°C]
        d_seq : numpy.ndarray of shape (n, 5)
            Disturbance of each step, [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of seats, V km/h].

        Returns
        -------
        numpy.ndarray of shape (n, 9)
            Temperatures after each step. [°C]
        """
        out = np.empty((len(d_seq), N))
        x = np.asarray(x0, dtype=float)
        for k, d in enumerate(np.asarray(d_seq, dtype=float)):
            x = self.step(x, d)
            out[k] = x
        return out
