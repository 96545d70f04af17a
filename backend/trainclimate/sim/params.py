"""Physical and control parameters of one half coach of a Regio-Dosto (RABe 511) double-deck car.

The paper publishes no parameter values; every default here is derived in ``docs/model.md`` from
the RABe 511 geometry (car width 2.8 m, height 4.6 m, ~25 m per car, ~89 seats per car, lower floor
0.44 m and upper floor 2.5 m above rail) and textbook rail-vehicle values. Arrays of three are per
deck in the order ``up, mid, low``; the three chassis parts are ``up`` (roof and upper side walls),
``mid`` (the floor between the decks) and ``low`` (floor, underframe and lower side walls).

A :class:`CoachParams` describes one coach; :func:`stack` turns several into one whose array
fields carry a leading coach axis, which is what the vectorised fleet simulator consumes.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trainclimate.sim.plausible import ENTRY_NAMES, PLAUSIBLE, Plausible

DECKS = ("up", "mid", "low")

#: Specific heat capacity of air at constant pressure, J/(kg K).
AIR_CP_J_KG_K = 1005.0
#: Density of air at ~20 °C and the Swiss Plateau's pressure, kg/m³.
AIR_DENSITY_KG_M3 = 1.2
#: Stefan–Boltzmann constant, W/(m² K⁴).
STEFAN_BOLTZMANN = 5.670374419e-8
#: The key of a calibrated twin's record in a coach-params file (``calibrate --out``,
#: :mod:`trainclimate.twin.validity`): not a parameter, skipped by :func:`load_params`.
TWIN_KEY = "twin"


class ParamsError(ValueError):
    """A coach parameter set is malformed or non-physical."""


def _a(*values: float) -> np.ndarray:
    return np.array(values, dtype=float)


def _default_distribution() -> np.ndarray:
    """Λ (6×6): column j is where input j = [Q_hvac up,mid,low; Q_fw up,mid,low] ends up.

    Rows are Q_act = [Q_room up,mid,low; Q_chassis up,mid,low]. Each column sums to 1 (paper,
    Section II.C). The pattern follows the paper's Figure 3: the upper HVAC outlet feeds the upper
    deck, the middle floor and the roof; the lower one the lower and middle decks and the
    underframe; part of each input is lost into the structure (ducts in the roof and underframe,
    floor heating in the floors).
    """
    lam = np.zeros((6, 6))
    # columns: hvac_up, hvac_mid, hvac_low, fw_up, fw_mid, fw_low
    lam[:, 0] = [0.82, 0.03, 0.00, 0.12, 0.03, 0.00]
    lam[:, 1] = [0.03, 0.85, 0.02, 0.05, 0.00, 0.05]
    lam[:, 2] = [0.00, 0.03, 0.82, 0.00, 0.05, 0.10]
    lam[:, 3] = [0.55, 0.00, 0.00, 0.15, 0.30, 0.00]
    lam[:, 4] = [0.00, 0.60, 0.00, 0.10, 0.00, 0.30]
    lam[:, 5] = [0.00, 0.00, 0.55, 0.00, 0.05, 0.40]
    return lam


@dataclass(frozen=True)
class CoachParams:
    """Parameters of one half coach of a Regio-Dosto double-deck car.

    After :func:`stack` every field carries a leading coach axis of length N: a scalar becomes
    shape (N,), an array of shape (k,) becomes (N, k). Per-deck arrays are ordered ``up, mid,
    low``. Units are also in the field names: ``_j_k`` J/K, ``_w_k`` W/K, ``_w`` W, ``_m2`` m²,
    ``_k`` K, ``_c`` °C, ``_s`` s, ``_m3_h`` m³/h, ``_kg_s`` kg/s; fractions are dimensionless.
    The defaults are derived in docs/model.md.

    Attributes
    ----------
    c_room_j_k, c_inv_j_k, c_chassis_j_k : numpy.ndarray of shape (3,)
        Heat capacities m_p^d c_p^d of Eq. (1) [1]_ of the deck air, the inventory and the
        chassis parts up, mid, low. [J/K]
    ua_deck_deck_w_k : numpy.ndarray of shape (2,)
        Air exchange between decks through the stairwells, [up–mid, mid–low]. [W/K]
    ua_room_inv_w_k : numpy.ndarray of shape (3,)
        Deck air ↔ inventory (seats, linings), per deck. [W/K]
    ua_room_chassis_w_k : numpy.ndarray of shape (3, 3)
        Deck air (rows up, mid, low) ↔ chassis part (columns up, mid, low); envelope U·A for the
        outer parts, interior film for the middle floor. [W/K]
    ua_chassis_chassis_w_k : numpy.ndarray of shape (3,)
        Conduction between chassis parts, [up–mid, mid–low, up–low]. [W/K]
    area_ext_m2 : numpy.ndarray of shape (2,)
        Outer surface of the [upper, lower] chassis exchanging heat with the environment. [m²]
    roof_area_m2 : float
        Roof area receiving the roof irradiance Q_Gt. [m²]
    roof_absorptance, side_absorptance : float
        Solar absorptance of the roof and of the side walls. [–]
    side_area_m2 : numpy.ndarray of shape (2,)
        Sunlit opaque side wall of the [upper, lower] chassis (one side of the car). [m²]
    window_area_m2 : numpy.ndarray of shape (3,)
        Sunlit window area per deck (one side of the car). [m²]
    window_g : float
        Solar energy transmittance (g-value) of the windows. [–]
    ground_area_m2, ground_emissivity : float
        Effective emissivity × view factor × area of the underframe seen by the track, as an
        area [m²] and an emissivity [–].
    ground_threshold_c : float
        Ground radiation acts only above this ambient temperature (paper: 20 °C). [°C]
    ground_slope : float
        s in the assumed track temperature T_G = T_amb + s · (T_amb − ground_threshold_c)
        (docs/model.md). [K/K]
    seats : numpy.ndarray of shape (3,)
        Seats per deck; passengers = occupancy (% of seats) / 100 × seats.
    heat_per_passenger_w : float
        Heat given off by each passenger (paper: 100 W). [W]
    door_mass_flow_kg_s : float
        Air exchanged through the open lower-deck door. [kg/s]
    supply_air_m3_h : float
        Supply air flow of the HVAC unit. [m³/h]
    air_share : numpy.ndarray of shape (3,)
        Share of the supply air delivered to each deck; sums to 1. [–]
    fresh_air_base_fraction : float
        Base fresh-air share of the supply air (keeps the car body over-pressured). [–]
    fresh_air_per_passenger_m3_h : float
        Minimum fresh air per passenger. [m³/h]
    q_heat_max_w, q_cool_max_w, q_fw_max_w : numpy.ndarray of shape (3,)
        Maximum HVAC heating and cooling output and maximum floor/wall heating, per deck. [W]
    fw_curve_t_amb_c, fw_curve_fraction : numpy.ndarray of shape (2,)
        Floor/wall heating in the heating state, piecewise linear: T_amb breakpoints (strictly
        increasing) [°C] and the fraction of ``q_fw_max_w`` at each [–].
    distribution : numpy.ndarray of shape (6, 6)
        Heat distribution Λ, Q_act = Λ Q_in (Section II.C [1]_): column j is where input j of
        [Q_hvac up, mid, low; Q_fw up, mid, low] ends up, rows [Q_room up, mid, low; Q_chassis
        up, mid, low]; every column sums to 1. [–]
    pid_kp_w_k : numpy.ndarray of shape (3,)
        Proportional gain of each deck's PID. [W/K]
    pid_ti_s, pid_td_s : numpy.ndarray of shape (3,)
        Integral and derivative time of each deck's PID. [s]
    pid_rate_w_s : numpy.ndarray of shape (3,)
        Rate limit of each PID's output. [W/s]
    pre_enter_k, pre_exit_k : float
        Preheating (precooling) starts when the mean room temperature is more than
        ``pre_enter_k`` below (above) T_ref and ends within ``pre_exit_k`` of it. [K]
    heat_below_k, cool_above_k, climate_hysteresis_k : float
        Heating state for T_amb < T_ref − ``heat_below_k``, cooling for T_amb > T_ref −
        ``cool_above_k``, the room's choice between; each switch with ``climate_hysteresis_k``.
        [K]
    climate_from_room : float
        1: between those ambient thresholds the decks choose (:func:`~trainclimate.sim.hvac.
        next_state`): cooling while none asks for heat, heating while none asks for cooling,
        mixed when they pull both ways; 0: always mixed there (the ambient alone). [–]
    climate_room_band_k : float
        How far the mean room temperature may drift past T_ref, in the state the decks chose,
        before the coach goes back to mixed. [K]
    cooling_min_off_s : float
        Minimum off time of a deck's cooling after it stopped, the compressor protection a
        real unit may have (0: none). [s]
    slumber_enter_k, slumber_exit_k, slumber_vent_k : float
        Slumber-mode band around T_ref: active heating/cooling enter and exit thresholds and
        the active-ventilation threshold. [K]
    slumber_capacity : float
        Fraction of the maximum HVAC output available in slumber mode. [–]
    economiser_band_k : float
        How much warmer (heating) or cooler (cooling) outside air must be than the coach to be
        drawn in instead of recirculated air. [K]
    heater_efficiency : float
        Efficiency η of the resistive heaters. [–]
    cop_a, cop_b, cop_min, cop_max : float
        COP = clip(cop_a − cop_b · T_amb, cop_min, cop_max) of the cooling circuit, T_amb in
        °C (``cop_b`` in 1/K). [–]
    fan_supply_w, fan_condenser_w : float
        Supply fans' power while the unit runs; condenser fans' power at full compressor
        load. [W]
    cop_carnot_efficiency : float
        0: the COP depends on T_amb alone (``cop_a`` … ``cop_max``); > 0: the Carnot-efficiency
        model, COP = η · T_e / (T_c − T_e) with η this value, the evaporating temperature T_e
        below the mixed return/fresh air and the condensing temperature T_c above T_amb by the
        approaches below, clipped to [``cop_min``, ``cop_max``] (docs/model.md). [–]
    evaporator_approach_k, condenser_approach_k : float
        T_mix − T_e and T_c − T_amb of the Carnot-efficiency model. [K]
    part_load_degradation : float
        Cd of EN 14825: below ``compressor_min_fraction`` of its capacity the compressor
        cycles, and its COP falls by the factor 1 − Cd · (1 − load / minimum); 0: none. [–]
    compressor_min_fraction : float
        The lowest share of its capacity the compressor modulates down to. [–]
    fan_condenser_cycling : float
        0: the condenser fans' power follows the compressor's load; 1: they run at full power
        whenever the compressor runs. [–]
    fan_supply_min_fraction : float
        1: the supply fans draw ``fan_supply_w`` whenever the unit runs; below 1 their power
        follows the unit's load, from this share at no load to all of it at full load. [–]
    sensor_noise_k, sensor_quantum_k : float
        Standard deviation of the room sensors' Gaussian noise and their quantisation step. [K]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II, Eq. (1).
    """

    # --- thermal capacities (Eq. (1): m_p^d c_p^d) -----------------------------------------
    c_room_j_k: np.ndarray = field(default_factory=lambda: _a(90e3, 60e3, 105e3))
    c_inv_j_k: np.ndarray = field(default_factory=lambda: _a(0.42e6, 0.20e6, 0.38e6))
    c_chassis_j_k: np.ndarray = field(default_factory=lambda: _a(1.40e6, 0.70e6, 1.80e6))
    # --- convection and conduction ----------------------------------------------------------
    ua_deck_deck_w_k: np.ndarray = field(default_factory=lambda: _a(120.0, 120.0))
    ua_room_inv_w_k: np.ndarray = field(default_factory=lambda: _a(240.0, 100.0, 232.0))
    ua_room_chassis_w_k: np.ndarray = field(
        default_factory=lambda: np.array(
            [[86.0, 125.0, 0.0], [41.0, 0.0, 32.0], [0.0, 125.0, 88.0]]
        )
    )
    ua_chassis_chassis_w_k: np.ndarray = field(default_factory=lambda: _a(40.0, 40.0, 16.0))
    area_ext_m2: np.ndarray = field(default_factory=lambda: _a(83.0, 87.0))
    # --- solar and ground radiation ---------------------------------------------------------
    roof_area_m2: float = 35.0
    roof_absorptance: float = 0.6
    side_area_m2: np.ndarray = field(default_factory=lambda: _a(17.7, 17.3))
    side_absorptance: float = 0.45
    window_area_m2: np.ndarray = field(default_factory=lambda: _a(5.5, 2.5, 5.0))
    window_g: float = 0.40
    ground_area_m2: float = 35.0
    ground_emissivity: float = 0.85
    ground_threshold_c: float = 20.0
    ground_slope: float = 1.0
    # --- passengers, doors, ventilation -----------------------------------------------------
    seats: np.ndarray = field(default_factory=lambda: _a(20.0, 8.0, 17.0))
    heat_per_passenger_w: float = 100.0
    door_mass_flow_kg_s: float = 0.25
    supply_air_m3_h: float = 3600.0
    air_share: np.ndarray = field(default_factory=lambda: _a(0.36, 0.22, 0.42))
    fresh_air_base_fraction: float = 0.15
    fresh_air_per_passenger_m3_h: float = 20.0
    # --- HVAC capacities and heat distribution ----------------------------------------------
    q_heat_max_w: np.ndarray = field(default_factory=lambda: _a(9000.0, 5000.0, 10000.0))
    q_cool_max_w: np.ndarray = field(default_factory=lambda: _a(8500.0, 4500.0, 9000.0))
    q_fw_max_w: np.ndarray = field(default_factory=lambda: _a(2000.0, 1200.0, 2800.0))
    fw_curve_t_amb_c: np.ndarray = field(default_factory=lambda: _a(-10.0, 15.0))
    fw_curve_fraction: np.ndarray = field(default_factory=lambda: _a(1.0, 0.0))
    distribution: np.ndarray = field(default_factory=_default_distribution)
    # --- PID per deck -------------------------------------------------------------------------
    pid_kp_w_k: np.ndarray = field(default_factory=lambda: _a(3000.0, 1800.0, 3300.0))
    pid_ti_s: np.ndarray = field(default_factory=lambda: _a(600.0, 600.0, 600.0))
    pid_td_s: np.ndarray = field(default_factory=lambda: _a(30.0, 30.0, 30.0))
    pid_rate_w_s: np.ndarray = field(default_factory=lambda: _a(300.0, 200.0, 300.0))
    # --- HVAC state machine thresholds (K relative to T_ref) --------------------------------
    pre_enter_k: float = 3.0
    pre_exit_k: float = 1.0
    heat_below_k: float = 8.0
    cool_above_k: float = 2.0
    climate_hysteresis_k: float = 1.0
    climate_from_room: float = 1.0
    climate_room_band_k: float = 0.5
    cooling_min_off_s: float = 0.0
    slumber_enter_k: float = 5.0
    slumber_exit_k: float = 4.0
    slumber_vent_k: float = 2.0
    slumber_capacity: float = 0.6
    economiser_band_k: float = 1.0
    # --- electrical power -------------------------------------------------------------------
    heater_efficiency: float = 1.0
    cop_a: float = 4.4
    cop_b: float = 0.06
    cop_min: float = 1.5
    cop_max: float = 4.5
    fan_supply_w: float = 1100.0
    fan_condenser_w: float = 800.0
    cop_carnot_efficiency: float = 0.0
    evaporator_approach_k: float = 10.0
    condenser_approach_k: float = 15.0
    part_load_degradation: float = 0.0
    compressor_min_fraction: float = 0.3
    fan_condenser_cycling: float = 0.0
    fan_supply_min_fraction: float = 1.0
    # --- sensors ----------------------------------------------------------------------------
    sensor_noise_k: float = 0.05
    sensor_quantum_k: float = 0.1

    # ------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Return the parameters as a JSON-ready dict (the ``coach-params`` file format).

        Returns
        -------
        dict
            Field name → float, or nested list for array fields, in the field names' units.
        """
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = value.tolist() if isinstance(value, np.ndarray) else float(value)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> CoachParams:
        """Build parameters from a (possibly partial) dict; missing keys take the defaults.

        Parameters
        ----------
        data : dict
            Field name → number or nested list of the default's shape, in the units of
            :class:`CoachParams` (e.g. the output of :meth:`to_dict`).

        Returns
        -------
        CoachParams
            The validated parameters of one coach.

        Raises
        ------
        ParamsError
            Naming the first unknown key, wrong shape, non-numeric or non-physical value.
        """
        if not isinstance(data, dict):
            raise ParamsError("coach parameters must be a JSON object")
        defaults = cls()
        known = {f.name: f for f in dataclasses.fields(cls)}
        kwargs = {}
        for key, value in data.items():
            if key not in known:
                raise ParamsError(f"unknown coach parameter {key!r}")
            default = getattr(defaults, key)
            try:
                if isinstance(default, np.ndarray):
                    arr = np.asarray(value, dtype=float)
                    if arr.shape != default.shape:
                        raise ParamsError(
                            f"coach parameter {key!r} must have shape {list(default.shape)}, "
                            f"got {list(arr.shape)}"
                        )
                    kwargs[key] = arr
                else:
                    if isinstance(value, bool) or not isinstance(value, int | float):
                        raise ParamsError(f"coach parameter {key!r} must be a number")
                    kwargs[key] = float(value)
            except (TypeError, ValueError) as exc:
                if isinstance(exc, ParamsError):
                    raise
                raise ParamsError(f"coach parameter {key!r} is not numeric") from exc
        params = dataclasses.replace(defaults, **kwargs)
        params.validate()
        return params

    def validate(self) -> None:
        """Check that every value is physical (for one coach, not a stacked set).

        Raises
        ------
        ParamsError
            If a value is not finite, a capacity, flow or gain is not positive, a conductance or
            area is negative, a fraction lies outside [0, 1], a column of Λ or ``air_share``
            does not sum to 1, the floor/wall curve is not increasing, an exit threshold is not
            below its entry threshold, ``cop_min`` exceeds ``cop_max``, or a value lies outside
            its plausible range (:mod:`~trainclimate.sim.plausible`: a capacity in kJ/K, say).
        """
        for f in dataclasses.fields(self):
            value = np.asarray(getattr(self, f.name), dtype=float)
            if not np.all(np.isfinite(value)):
                raise ParamsError(f"coach parameter {f.name!r} must be finite")
        positive = [
            "c_room_j_k",
            "c_inv_j_k",
            "c_chassis_j_k",
            "supply_air_m3_h",
            "pid_rate_w_s",
            "cop_a",
            "cop_min",
            "cop_max",
            "heater_efficiency",
        ]
        for name in positive:
            if np.any(np.asarray(getattr(self, name)) <= 0):
                raise ParamsError(f"coach parameter {name!r} must be > 0")
        non_negative = [
            "ua_deck_deck_w_k",
            "ua_room_inv_w_k",
            "ua_room_chassis_w_k",
            "ua_chassis_chassis_w_k",
            "area_ext_m2",
            "roof_area_m2",
            "side_area_m2",
            "window_area_m2",
            "ground_area_m2",
            "seats",
            "heat_per_passenger_w",
            "door_mass_flow_kg_s",
            "air_share",
            "fresh_air_per_passenger_m3_h",
            "q_heat_max_w",
            "q_cool_max_w",
            "q_fw_max_w",
            "pid_kp_w_k",
            "pid_td_s",
            "fan_supply_w",
            "fan_condenser_w",
            "sensor_noise_k",
            "sensor_quantum_k",
            "distribution",
            "ground_slope",
            "cop_b",
            "economiser_band_k",
            "climate_hysteresis_k",
            "climate_room_band_k",
            "cooling_min_off_s",
        ]
        for name in non_negative:
            if np.any(np.asarray(getattr(self, name)) < 0):
                raise ParamsError(f"coach parameter {name!r} must be >= 0")
        if np.any(self.pid_ti_s <= 0):
            raise ParamsError("coach parameter 'pid_ti_s' must be > 0")
        fractions = [
            "roof_absorptance",
            "side_absorptance",
            "window_g",
            "ground_emissivity",
            "fresh_air_base_fraction",
            "slumber_capacity",
            "fw_curve_fraction",
        ]
        for name in fractions:
            v = np.asarray(getattr(self, name))
            if np.any(v < 0) or np.any(v > 1):
                raise ParamsError(f"coach parameter {name!r} must lie in [0, 1]")
        col = self.distribution.sum(axis=0)
        if not np.allclose(col, 1.0, atol=1e-6):
            bad = int(np.argmax(np.abs(col - 1.0)))
            raise ParamsError(
                f"coach parameter 'distribution' (Λ): column {bad} sums to {col[bad]:.4f}, not 1"
            )
        if not np.isclose(self.air_share.sum(), 1.0, atol=1e-6):
            raise ParamsError("coach parameter 'air_share' must sum to 1")
        if np.any(np.diff(self.fw_curve_t_amb_c) <= 0):
            raise ParamsError("coach parameter 'fw_curve_t_amb_c' must be strictly increasing")
        if self.pre_exit_k >= self.pre_enter_k or self.slumber_exit_k >= self.slumber_enter_k:
            raise ParamsError("state machine exit thresholds must be below the entry thresholds")
        if self.cop_min > self.cop_max:
            raise ParamsError("coach parameter 'cop_min' must not exceed 'cop_max'")
        check_plausible(self)


def _implausible(name: str, value: np.ndarray, index: tuple[int, ...], plausible: Plausible) -> str:
    """The one-line message for entry ``index`` of field ``name`` (one coach's ``value``) lying
    outside ``plausible``, e.g. ``c_room_j_k[up] = 90 J/K is outside 10000 … 1e+06 J/K (…; kJ/K
    given?)``; the question is asked when the entry is too small and 1000 × it would fit."""
    low, high, unit, reason = plausible
    labels = [
        ENTRY_NAMES[name][i] if name in ENTRY_NAMES else DECKS[i] if n == 3 else str(i)
        for i, n in zip(index, value.shape, strict=True)
    ]
    entry = f"[{', '.join(labels)}]" if labels else ""
    x = float(value[index])
    unit_ = f" {unit}" if unit else ""
    kilo = unit[:1] in ("J", "W") and x < low and low <= 1e3 * x <= high
    hint = f"; k{unit} given?" if kilo else ""
    return f"{name}{entry} = {x:g}{unit_} is outside {low:g} … {high:g}{unit_} ({reason}{hint})"


def check_plausible(params: CoachParams) -> None:
    """Raise :class:`ParamsError` with a one-line message for the first field of ``params`` (one
    coach) with an entry outside its plausible range
    (:data:`~trainclimate.sim.plausible.PLAUSIBLE`)."""
    for name, plausible in PLAUSIBLE.items():
        value = np.asarray(getattr(params, name), dtype=float)
        outside = (value < plausible.low) | (value > plausible.high)
        if np.any(outside):
            index = tuple(int(i) for i in np.argwhere(outside)[0])
            raise ParamsError(_implausible(name, value, index, plausible))


#: Parameters that differ between real coaches (manufacturing, ageing, fit-out) and are varied
#: by :func:`diversify`. Control software settings (PID gains, thresholds) are the same on every
#: coach and are not varied.
VARIED = (
    "c_room_j_k",
    "c_inv_j_k",
    "c_chassis_j_k",
    "ua_deck_deck_w_k",
    "ua_room_inv_w_k",
    "ua_room_chassis_w_k",
    "ua_chassis_chassis_w_k",
    "area_ext_m2",
    "roof_absorptance",
    "side_absorptance",
    "window_g",
    "ground_emissivity",
    "door_mass_flow_kg_s",
    "supply_air_m3_h",
    "q_heat_max_w",
    "q_cool_max_w",
    "q_fw_max_w",
    "distribution",
    "cop_a",
    "fan_supply_w",
)


def diversify(base: CoachParams, n: int, *, seed: int, spread: float = 0.15) -> list[CoachParams]:
    """Draw ``n`` coach parameter sets scattered around ``base``.

    Each varied parameter (see :data:`VARIED`) is multiplied element-wise by an independent
    factor drawn uniformly from [1 − spread, 1 + spread]. Λ's entries are perturbed and its
    columns renormalised to sum to 1; fractions are clipped to [0, 1].

    Parameters
    ----------
    base : CoachParams
        The parameters to scatter around (one coach).
    n : int
        Number of parameter sets to draw.
    seed : int
        Seed of the random generator; the same seed gives the same sets.
    spread : float, default 0.15
        Relative half-width of the uniform factor (±15 %, inside the ±10–20 % the fleet
        shows). [–]

    Returns
    -------
    list of CoachParams
        ``n`` parameter sets; the first equals ``base`` only if ``spread`` is 0.

    Raises
    ------
    ValueError
        If ``spread`` is outside [0, 1).
    """
    if not 0 <= spread < 1:
        raise ValueError("spread must lie in [0, 1)")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        changes = {}
        for name in VARIED:
            value = np.asarray(getattr(base, name), dtype=float)
            factor = rng.uniform(1 - spread, 1 + spread, size=value.shape)
            new = value * factor
            if name == "distribution":
                new = new / new.sum(axis=0, keepdims=True)
            elif name in ("roof_absorptance", "side_absorptance", "window_g", "ground_emissivity"):
                new = np.clip(new, 0.0, 1.0)
            changes[name] = new if value.ndim else float(new)
        out.append(dataclasses.replace(base, **changes))
    return out


def stack(params: list[CoachParams]) -> CoachParams:
    """Stack several coaches' parameters for the vectorised fleet simulator.

    Parameters
    ----------
    params : list of CoachParams
        One parameter set per coach, N = ``len(params)``.

    Returns
    -------
    CoachParams
        One set whose every field has a leading coach axis of length N.

    Raises
    ------
    ValueError
        If ``params`` is empty.
    """
    if not params:
        raise ValueError("need at least one coach")
    kwargs = {
        f.name: np.stack([np.asarray(getattr(p, f.name), dtype=float) for p in params])
        for f in dataclasses.fields(CoachParams)
    }
    return CoachParams(**kwargs)


def load_params(path: str | Path) -> CoachParams:
    """Read a ``coach-params`` JSON file (the format of ``trainclimate coach-params --default``).

    Parameters
    ----------
    path : str or pathlib.Path
        The JSON file; missing keys take the defaults (see :meth:`CoachParams.from_dict`),
        :data:`TWIN_KEY` is skipped.

    Returns
    -------
    CoachParams
        The file's parameters, completed with the defaults and validated.

    Raises
    ------
    ParamsError
        If the file is missing, not valid JSON, or holds an unknown, malformed or non-physical
        value.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ParamsError(f"coach parameter file not found: {path}") from exc
    except json.JSONDecodeError as exc:
        raise ParamsError(f"coach parameter file {path} is not valid JSON: {exc.msg}") from exc
    if isinstance(data, dict):  # a twin's calibration record (trainclimate.twin.validity)
        data = {k: v for k, v in data.items() if k != TWIN_KEY}
    return CoachParams.from_dict(data)
