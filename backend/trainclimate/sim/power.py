"""Electrical power of the HVAC: the quantity every energy saving is measured in.

The paper's experiments measured the HVAC's electrical power with external loggers, so savings
are counted on electrical, not thermal, power, on the meters that sum its components
(:mod:`trainclimate.coach.meters`). Components (all W, vectorised over coaches):

- heating elements in the HVAC unit: ``Q_heat / η`` (resistive, η ≈ 1);
- floor and wall heating: ``Q_fw / η`` (resistive);
- compressor: ``Q_cool / COP``. By default the COP falls linearly as the condenser's air gets
  warmer, ``COP = clip(cop_a − cop_b · T_amb, cop_min, cop_max)`` (≈ 3.2 at 20 °C and 2.5 at
  32 °C, the range rail air-conditioning units reach at EN 14750 rating conditions). With
  ``cop_carnot_efficiency`` η > 0 it depends on both sides of the cycle, a Carnot-efficiency
  model [2]_: ``COP = η · T_e / (T_c − T_e)`` (kelvin), the evaporating temperature T_e
  ``evaporator_approach_k`` below the air entering the evaporator — the mixed return and fresh
  air, ``f · T_amb + (1 − f) · T_room`` — and the condensing temperature T_c
  ``condenser_approach_k`` above T_amb, clipped to [``cop_min``, ``cop_max``];
- part load (EN 14825 [3]_): below ``compressor_min_fraction`` of its capacity the compressor
  cycles, and its COP falls by ``1 − Cd · (1 − CR)``, CR the load over that minimum and Cd
  ``part_load_degradation`` (0 by default; 0.25 is the standard's value when not measured);
- supply fans whenever the unit runs — constant, or following the unit's load from
  ``fan_supply_min_fraction`` of their power at no load — and condenser fans in proportion to the
  compressor load, or at full power whenever it runs (``fan_condenser_cycling``).

References
----------
.. [2] M. Wetter, W. Zuo, T. S. Nouidui, X. Pang, Modelica Buildings library, Journal of Building
   Performance Simulation 7(4), 2014: the Carnot-efficiency chiller and heat-pump models
   (``Buildings.Fluid.Chillers.Carnot_y``).
.. [3] EN 14825:2022, Air conditioners, liquid chilling packages and heat pumps … — Testing and
   rating at part load conditions and calculation of seasonal performance: the degradation
   coefficient Cd (default 0.25) for units cycling on and off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trainclimate.sim.params import CoachParams

#: 0 °C in kelvin.
KELVIN = 273.15


def cop(t_amb_c: np.ndarray, p: CoachParams, t_mix_c: np.ndarray | None = None) -> np.ndarray:
    """Coefficient of performance of the cooling circuit at full load (see the module).

    COP = clip(cop_a − cop_b · T_amb, cop_min, cop_max), or with ``cop_carnot_efficiency``
    η > 0 and the evaporator's inlet air ``t_mix_c``, clip(η · T_e / (T_c − T_e), cop_min,
    cop_max) with T_e = T_mix − ``evaporator_approach_k`` and T_c = T_amb +
    ``condenser_approach_k`` in kelvin (T_c − T_e at least 1 K).

    Parameters
    ----------
    t_amb_c : numpy.ndarray
        Ambient temperature, shape (N,) or broadcastable against the stacked parameters. [°C]
    p : CoachParams
        Parameters, stacked (:func:`~trainclimate.sim.params.stack`) for arrays of coaches.
    t_mix_c : numpy.ndarray, optional
        Air entering the evaporator (mixed return and fresh air), like ``t_amb_c``; without it
        the Carnot-efficiency model is not used. [°C]

    Returns
    -------
    numpy.ndarray
        The COP, same shape as ``t_amb_c``. [–]
    """
    linear = np.clip(p.cop_a - p.cop_b * t_amb_c, p.cop_min, p.cop_max)
    if t_mix_c is None:
        return linear
    t_e = t_mix_c - p.evaporator_approach_k + KELVIN
    t_c = t_amb_c + p.condenser_approach_k + KELVIN
    carnot = p.cop_carnot_efficiency * t_e / np.maximum(t_c - t_e, 1.0)
    return np.where(p.cop_carnot_efficiency > 0, np.clip(carnot, p.cop_min, p.cop_max), linear)


def part_load_factor(load: np.ndarray, p: CoachParams) -> np.ndarray:
    """The COP's factor at a compressor ``load`` (share of its capacity, (N,)) [3]_: 1 at or
    above ``compressor_min_fraction``, 1 − Cd · (1 − CR) below it, CR = load / minimum."""
    cr = np.clip(load / p.compressor_min_fraction, 0.0, 1.0)
    return 1.0 - p.part_load_degradation * (1.0 - cr)


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
    t_mix_c: np.ndarray | None = None,
) -> Power:
    """Electrical power of the HVAC for its thermal outputs (see the module).

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
    t_mix_c : numpy.ndarray of shape (N,), optional
        Air entering the evaporator, for the Carnot-efficiency COP. [°C]

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
    unit_load = np.maximum(load, q_heat / p.q_heat_max_w.sum(axis=1))
    supply = p.fan_supply_min_fraction + (1.0 - p.fan_supply_min_fraction) * unit_load
    condenser = np.where(p.fan_condenser_cycling > 0, (q_cool > 0).astype(float), load)
    return Power(
        heater_w=q_heat / p.heater_efficiency,
        floor_wall_w=q_fw_w.sum(axis=1) / p.heater_efficiency,
        compressor_w=q_cool / (cop(t_amb_c, p, t_mix_c) * part_load_factor(load, p)),
        fans_w=p.fan_supply_w * supply * fans_on + p.fan_condenser_w * condenser,
    )
