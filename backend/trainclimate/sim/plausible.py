"""The plausible range of every coach parameter.

The ranges span orders of magnitude around the defaults derived in ``docs/model.md`` (section
"Plausible ranges"): a value outside is a unit slip (kJ/K for J/K, kW for W) or not a Regio-Dosto
half coach. :meth:`~trainclimate.sim.params.CoachParams.validate` checks a parameter set against
them (:func:`~trainclimate.sim.params.check_plausible`); this module imports nothing of the
package, so that :mod:`~trainclimate.sim.params` can import it.
"""

from __future__ import annotations

from typing import NamedTuple


class Plausible(NamedTuple):
    """The plausible range of a coach parameter: each of its entries lies in [low, high]."""

    low: float
    high: float
    unit: str  # "" for a dimensionless value
    reason: str  # what the value is, as the error message says it


#: Plausible range of every field of :class:`CoachParams`, orders of magnitude around the
#: defaults derived in docs/model.md (section "Plausible ranges"); a value outside is a unit
#: slip (kJ/K for J/K, kW for W) or not a Regio-Dosto half coach. Per deck unless said.
PLAUSIBLE: dict[str, Plausible] = {
    # thermal capacities
    "c_room_j_k": Plausible(1e4, 1e6, "J/K", "a deck's air and light fittings, ~30–120 kJ/K"),
    "c_inv_j_k": Plausible(1e4, 1e7, "J/K", "a deck's seats, linings and floor, ~0.2–0.4 MJ/K"),
    "c_chassis_j_k": Plausible(1e5, 1e8, "J/K", "a part of the aluminium body, ~0.7–1.8 MJ/K"),
    # convection and conduction
    "ua_deck_deck_w_k": Plausible(10, 5e3, "W/K", "air exchange through a stairwell, ~120 W/K"),
    "ua_room_inv_w_k": Plausible(10, 5e3, "W/K", "a deck's inventory, ~100–240 W/K"),
    "ua_room_chassis_w_k": Plausible(0, 5e3, "W/K", "deck–chassis U·A ~30–125 W/K, 0: none"),
    "ua_chassis_chassis_w_k": Plausible(1, 2e3, "W/K", "conduction in the body, ~16–40 W/K"),
    "area_ext_m2": Plausible(10, 500, "m²", "outer surface of the upper or lower chassis, ~85 m²"),
    # solar and ground radiation
    "roof_area_m2": Plausible(5, 100, "m²", "roof of a half coach, 12.5 m × 2.8 m"),
    "roof_absorptance": Plausible(0.1, 1, "", "solar absorptance of paint, white ~0.2"),
    "side_area_m2": Plausible(2, 100, "m²", "one side's opaque wall, ~17 m²"),
    "side_absorptance": Plausible(0.1, 1, "", "solar absorptance of paint, white ~0.2"),
    "window_area_m2": Plausible(0.5, 30, "m²", "one side's glazing of a deck, ~2.5–5.5 m²"),
    "window_g": Plausible(0.05, 0.9, "", "g-value of glazing, reflective ~0.1, clear ~0.85"),
    "ground_area_m2": Plausible(1, 100, "m²", "underframe seen by the track, ~35 m²"),
    "ground_emissivity": Plausible(0, 1, "", "emissivity × view factor of the underframe, ~0.85"),
    "ground_threshold_c": Plausible(0, 40, "°C", "the track radiates above it, paper: 20 °C"),
    "ground_slope": Plausible(0, 3, "K/K", "track warming per K of ambient, ~1"),
    # passengers, doors, ventilation
    "seats": Plausible(0, 60, "", "seats on a deck of a half coach, ~45 in all"),
    "heat_per_passenger_w": Plausible(50, 200, "W", "heat of a seated person, ~100 W"),
    "door_mass_flow_kg_s": Plausible(0, 3, "kg/s", "air through an open door, ~0.25 kg/s"),
    "supply_air_m3_h": Plausible(500, 2e4, "m³/h", "supply fans of one HVAC unit, ~3600 m³/h"),
    "air_share": Plausible(0.05, 0.9, "", "a deck's share of the supply air, ~0.2–0.4"),
    "fresh_air_base_fraction": Plausible(0, 1, "", "base share of outside air, ~0.15"),
    "fresh_air_per_passenger_m3_h": Plausible(2, 200, "m³/h", "EN 14750-1 order, ~20 m³/h"),
    # HVAC capacities and heat distribution
    "q_heat_max_w": Plausible(500, 1e5, "W", "a deck's share of the unit's ~24 kW heater"),
    "q_cool_max_w": Plausible(500, 1e5, "W", "a deck's share of the unit's ~22 kW cooling"),
    "q_fw_max_w": Plausible(100, 3e4, "W", "a deck's share of ~6 kW floor/wall heating"),
    "fw_curve_t_amb_c": Plausible(-40, 40, "°C", "curve breakpoints, −10 and 15 °C"),
    "fw_curve_fraction": Plausible(0, 1, "", "share of the floor/wall heating at a breakpoint"),
    "distribution": Plausible(0, 1, "", "share of an input reaching a node (Λ)"),
    # PID per deck
    "pid_kp_w_k": Plausible(100, 1e5, "W/K", "full output at 0.1–10 K error"),
    "pid_ti_s": Plausible(30, 1e4, "s", "integral time of a deck's PID, ~600 s"),
    "pid_td_s": Plausible(0, 600, "s", "derivative time, 0 for PI control"),
    "pid_rate_w_s": Plausible(10, 1e4, "W/s", "output from 0 to full in ~1 s to ~15 min"),
    # HVAC state machine thresholds, relative to T_ref
    "pre_enter_k": Plausible(0.5, 10, "K", "preheating starts this far from T_ref, ~3 K"),
    "pre_exit_k": Plausible(0, 5, "K", "preheating ends this close to T_ref, ~1 K"),
    "heat_below_k": Plausible(0, 20, "K", "heating below T_ref minus this, ~8 K"),
    "cool_above_k": Plausible(-10, 10, "K", "cooling above T_ref minus this, ~2 K"),
    "climate_hysteresis_k": Plausible(0, 5, "K", "hysteresis of the climate states, ~1 K"),
    "climate_from_room": Plausible(0, 1, "", "1: the decks choose between the thresholds"),
    "climate_room_band_k": Plausible(0, 3, "K", "the mean's drift before mixed, ~0.5 K"),
    "cooling_min_off_s": Plausible(0, 1800, "s", "a deck's cooling minimum off time; 0: none"),
    "slumber_enter_k": Plausible(1, 15, "K", "slumber band's entry threshold, ~5 K"),
    "slumber_exit_k": Plausible(0, 15, "K", "slumber band's exit threshold, ~4 K"),
    "slumber_vent_k": Plausible(0, 10, "K", "slumber band's ventilation threshold, ~2 K"),
    "slumber_capacity": Plausible(0.1, 1, "", "share of the HVAC output in slumber mode, ~0.6"),
    "economiser_band_k": Plausible(0, 5, "K", "margin for drawing in outside air, ~1 K"),
    # electrical power
    "heater_efficiency": Plausible(0.5, 1, "", "efficiency of a resistive heater, ~1"),
    "cop_a": Plausible(1, 10, "", "COP of a rail cooling unit at 0 °C, ~4.4"),
    "cop_b": Plausible(0, 0.3, "1/K", "fall of the COP per K of ambient, ~0.06"),
    "cop_min": Plausible(0.5, 5, "", "lowest COP of a rail cooling unit, ~1.5"),
    "cop_max": Plausible(1, 10, "", "highest COP of a rail cooling unit, ~4.5"),
    "fan_supply_w": Plausible(50, 1e4, "W", "supply fans of one HVAC unit, ~1.1 kW"),
    "fan_condenser_w": Plausible(50, 1e4, "W", "condenser fans of one HVAC unit, ~0.8 kW"),
    "cop_carnot_efficiency": Plausible(0, 0.8, "", "second-law efficiency η, ~0.3; 0: off"),
    "evaporator_approach_k": Plausible(0, 30, "K", "mixed air above evaporating, ~10 K"),
    "condenser_approach_k": Plausible(0, 40, "K", "condensing above outside air, ~15 K"),
    "part_load_degradation": Plausible(0, 1, "", "EN 14825's Cd, 0.25 by default; 0: off"),
    "compressor_min_fraction": Plausible(0.01, 1, "", "lowest modulation of the compressor"),
    "fan_condenser_cycling": Plausible(0, 1, "", "1: condenser fans on with the compressor"),
    "fan_supply_min_fraction": Plausible(0, 1, "", "1: constant supply fans"),
    # sensors
    "sensor_noise_k": Plausible(0, 1, "K", "noise of a PT100 room sensor, ~0.05 K"),
    "sensor_quantum_k": Plausible(0, 1, "K", "resolution of the logged readings, 0.1 K"),
}

#: Entry names of the array fields whose entries are not per deck, for error messages; the
#: other length-3 axes are the decks or chassis parts ``up, mid, low``, the rest are numbered.
ENTRY_NAMES = {
    "ua_deck_deck_w_k": ("up–mid", "mid–low"),
    "ua_chassis_chassis_w_k": ("up–mid", "mid–low", "up–low"),
    "area_ext_m2": ("upper", "lower"),
    "side_area_m2": ("upper", "lower"),
}
