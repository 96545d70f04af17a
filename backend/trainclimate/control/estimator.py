"""State estimate of a coach: the unmeasured inventory and chassis temperatures (Kalman filter).

T_opt needs the whole thermal state, but only the room temperatures are measured. The filter runs
on the controller's discrete coach model (:mod:`.coach_model`) with the state augmented by the
heat that enters each room unmeasured — the HVAC's output, the ventilation air, the doors, which
the controller never sees — modelled as a random walk:

    x(k+1) = A_d x(k) + B_d [T_amb; q_known(k) + Λ_hvac q_u(k)],   q_u(k+1) = q_u(k) + w(k)
    y(k)   = [I₃ 0] x(k) + v(k)

(Λ_hvac, the HVAC columns of the heat distribution, spreads q_u over rooms and structure as the
plant spreads the HVAC's heat). Process noise: 0.02 K per step on the temperatures (model
error) and 2 kW per step on q_u (the HVAC can change its output that fast); measurement noise:
0.06 K (the sensors' 0.05 K noise and 0.1 K quantisation). Its accuracy against the simulator's
true states is measured in the tests and documented in docs/controller.md.
"""

from __future__ import annotations

import numpy as np

from trainclimate.control.coach_model import CoachModel, N

NQ = 3


class StateEstimator:
    """A Kalman filter over x = [T_room, T_inv, T_chassis] (°C) and q_u (W into each room).

    :meth:`reset` starts it from a measurement; :meth:`update` advances it one controller step
    with the disturbance that acted over the step and the new measurement.

    Parameters
    ----------
    model : CoachModel
        The controller's discrete coach model (its step is the filter's).
    temp_noise_k : float, default 0.02
        Process noise on the temperatures per step (standard deviation). [K]
    heat_noise_w : float, default 2000.0
        Process noise on q_u per step (standard deviation). [W]
    meas_noise_k : float, default 0.06
        Measurement noise (standard deviation). [K]

    Attributes
    ----------
    x : numpy.ndarray of shape (12,)
        The estimate [T_room; T_inv; T_chassis (°C); q_u (W)], NaN before :meth:`reset`.
    P : numpy.ndarray of shape (12, 12)
        Its covariance.
    """

    def __init__(
        self,
        model: CoachModel,
        *,
        temp_noise_k: float = 0.02,
        heat_noise_w: float = 2000.0,
        meas_noise_k: float = 0.06,
    ):
        self.model = model
        n = N + NQ
        self.Q = np.diag([temp_noise_k**2] * N + [heat_noise_w**2] * NQ)
        self.R = np.eye(3) * meas_noise_k**2
        self.C = np.zeros((3, n))
        self.C[:, :3] = np.eye(3)
        self.x = np.full(n, np.nan)
        self.P = np.eye(n)
        # q_u is the HVAC's output per deck, spread over rooms and structure like the HVAC's heat:
        # by the HVAC columns of Λ (rows room up, mid, low, chassis up, mid, low)
        spread = np.zeros((N, NQ))
        spread[[0, 1, 2, 6, 7, 8], :] = model.params.distribution[:, :NQ]
        self._F = []
        for i in range(len(model.A_d)):
            F = np.eye(n)
            F[:N, :N] = model.A_d[i]
            F[:N, N:] = model.B_d[i, :, 1:] @ spread
            self._F.append(F)

    @property
    def ready(self) -> bool:
        """Whether the filter holds a finite estimate (it has been reset)."""
        return bool(np.all(np.isfinite(self.x)))

    @property
    def temperatures(self) -> np.ndarray:
        """The estimated nine temperatures [T_room; T_inv; T_chassis], a copy, shape (9,). [°C]"""
        return self.x[:N].copy()

    @property
    def room_heat_w(self) -> np.ndarray:
        """The estimated unmeasured heat into each room (mostly the HVAC's), shape (3,). [W]"""
        return self.x[N:].copy()

    def reset(self, y: np.ndarray, t_amb_c: float) -> None:
        """Start from a measurement, with a wide uncertainty.

        The inventory starts at the room's temperature, the chassis halfway to ambient, with no
        unmeasured heat.

        Parameters
        ----------
        y : numpy.ndarray of shape (3,)
            Measured room temperatures up, mid, low. [°C]
        t_amb_c : float
            Ambient temperature. [°C]
        """
        y = np.asarray(y, dtype=float)
        chassis = 0.5 * (y + t_amb_c)
        self.x = np.concatenate([y, y, chassis, np.zeros(NQ)])
        self.P = np.diag([0.1**2] * 3 + [2.0**2] * 3 + [5.0**2] * 3 + [3000.0**2] * NQ)

    def update(self, d_prev: np.ndarray, y: np.ndarray) -> None:
        """One filter step: predict over the interval just ended, then correct.

        Parameters
        ----------
        d_prev : numpy.ndarray of shape (5,)
            The disturbance held over the interval just ended, [T_amb °C, Q_Gt W/m², Q_Gs W/m²,
            P % of seats, V km/h].
        y : numpy.ndarray of shape (3,)
            The new measurement of the room temperatures. [°C]
        """
        m = self.model
        i = m.grid_index(d_prev)
        temps = self.x[:N]
        q = m.known_heat_w(temps, d_prev)
        x_pred = self._F[i] @ self.x
        x_pred[:N] += m.B_d[i, :, 0] * d_prev[0] + m.B_d[i, :, 1:] @ q
        F = self._F[i]
        P_pred = F @ self.P @ F.T + self.Q
        S = self.C @ P_pred @ self.C.T + self.R
        K = np.linalg.solve(S, self.C @ P_pred).T
        self.x = x_pred + K @ (np.asarray(y, dtype=float) - x_pred[:3])
        I_KC = np.eye(len(self.x)) - K @ self.C
        self.P = I_KC @ P_pred @ I_KC.T + K @ self.R @ K.T  # Joseph form: stays symmetric PSD

    def run(self, y_seq: np.ndarray, d_seq: np.ndarray) -> None:
        """Reset on the first sample of a history and filter through the rest.

        Parameters
        ----------
        y_seq : numpy.ndarray of shape (n, 3)
            Measured room temperatures, oldest first. [°C]
        d_seq : numpy.ndarray of shape (n, 5)
            Disturbances, d_seq[k] acting over [k, k+1); as in :meth:`update`.
        """
        self.reset(y_seq[0], float(d_seq[0][0]))
        for k in range(1, len(y_seq)):
            self.update(d_seq[k - 1], y_seq[k])
