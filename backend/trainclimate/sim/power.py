"""Electrical power of the HVAC: the quantity every energy saving is measured in.

The paper's experiments measured the HVAC's electrical power with external loggers, so savings
are counted on electrical, not thermal, power. Components (all W, vectorised over coaches):

- heating elements in the HVAC unit: ``Q_heat / η`` (resistive, η ≈ 1);
- floor and wall heating: ``Q_fw / η`` (resistive);
- compressor: ``Q_cool / COP(T_amb)``, the COP falling linearly as the condenser's air gets
  warmer, ``COP = clip(cop_a − cop_b · T_amb, cop_min, cop_max)`` (≈ 3.2 at 20 °C and 2.5 at
  32 °C by default, the range rail air-conditioning units reach at EN 14750 rating conditions);
- supply fans whenever the unit runs, and condenser fans in proportion to the compressor load.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trainclimate.sim.params import CoachParams


def cop(t_amb_c: np.ndarray, p: CoachParams) -> np.ndarray:
    """Coefficient of performance of the cooling circuit.

    COP = clip(cop_a − cop_b · T_amb, cop_min, cop_max): the condenser works against warmer air
    as T_amb rises.

    Parameters
    ----------
    t_amb_c : numpy.ndarray
        Ambient temperature, shape (N,) or broadcastable against the stacked parameters. [°C]
    p : CoachParams
        Parameters, stacked (:func:`~trainclimate.sim.params.stack`) for arrays of coaches.

    Returns
    -------
    numpy.ndarray
        The COP, same shape as ``t_amb_c``. [–]
    """
    return np.clip(p.cop_a - p.cop_b * t_amb_c, p.cop_min, p.cop_max)


@dataclass
class Power:
    """Electrical power of the HVAC by component, for N coaches.

    Attributes
    ----------
    heater_w : numpy.ndarray of shape (N,)
        Resistive heating elements in the HVAC unit, Q_heat / η. [W]
    floor_wall_w : numpy.ndarray of shape (N,)
        Floor and wall heating, Q_fw / η. [W]
    compressor_w : numpy.ndarray of shape (N,)
        Compressor, Q_cool / COP(T_amb). [W]
    fans_w : numpy.ndarray of shape (N,)
        Supply fans (while the unit runs) and condenser fans (with the compressor load). [W]
    """

    heater_w: np.ndarray
    floor_wall_w: np.ndarray
    compressor_w: np.ndarray
    fans_w: np.ndarray

    @property
    def total_w(self) -> np.ndarray:
        """Total electrical power, the sum of the four components, shape (N,). [W]"""
        return self.heater_w + self.floor_wall_w + self.compressor_w + self.fans_w


def electrical_power(
    q_hvac_w: np.ndarray,
    q_fw_w: np.ndarray,
    t_amb_c: np.ndarray,
    fans_on: np.ndarray,
    p: CoachParams,
) -> Power:
    """Electrical power of the HVAC for its thermal outputs.

    Parameters
    ----------
    q_hvac_w : numpy.ndarray of shape (N, 3)
        HVAC heat flow per deck (up, mid, low); positive heats, negative cools. [W]
    q_fw_w : numpy.ndarray of shape (N, 3)
        Floor and wall heating per deck. [W]
    t_amb_c : numpy.ndarray of shape (N,)
        Ambient temperature. [°C]
    fans_on : numpy.ndarray of shape (N,)
        Whether the supply fans run (bool, or 0/1).
    p : CoachParams
        Parameters stacked over the N coaches.

    Returns
    -------
    Power
        The components, each of shape (N,), in W. The paper's experiments measured this
        electrical (not thermal) power, so every energy saving is counted on it [1]_.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section V.
    """
    q_heat = np.clip(q_hvac_w, 0.0, None).sum(axis=1)
    q_cool = np.clip(-q_hvac_w, 0.0, None).sum(axis=1)
    load = q_cool / p.q_cool_max_w.sum(axis=1)
    return Power(
        heater_w=q_heat / p.heater_efficiency,
        floor_wall_w=q_fw_w.sum(axis=1) / p.heater_efficiency,
        compressor_w=q_cool / cop(t_amb_c, p),
        fans_w=p.fan_supply_w * fans_on + p.fan_condenser_w * load,
    )
