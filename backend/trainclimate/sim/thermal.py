"""The coach block: nine temperatures and every heat flow of the paper's Section II.C.

State (per coach), in this order: ``T_room`` up, mid, low; ``T_inv`` up, mid, low; ``T_chassis``
up, mid, low (°C). Each obeys Eq. (1), ``dT_p^d/dt = (1 / m_p^d c_p^d) · Σ_i Q_p,i^d``. The heat
flows, all in W and all vectorised over a leading coach axis (shape ``(N,)``):

- input: ``Q_act = Λ Q_in`` into the three rooms and three chassis parts;
- convection: deck ↔ deck (up–mid, mid–low), deck ↔ inventory, deck ↔ chassis, and upper/lower
  chassis ↔ environment with a speed-dependent coefficient :func:`h_ext_w_m2_k`;
- conduction: between the chassis parts (up–mid, mid–low, up–low);
- solar: roof term ``Q_Gt`` on the upper chassis, side term ``Q_Gs`` on both chassis walls and
  through the windows into every deck (see :mod:`trainclimate.sim.solar` on the angle);
- ground radiation on the lower chassis, only above ``ground_threshold_c`` of T_amb;
- passengers (100 W each on their deck), the lower-deck door at stops, and the ventilation load
  of the fresh-air fraction.

Internal flows appear with opposite signs in two nodes, so the sum of ``C · dT/dt`` over the nine
nodes equals the sum of the external flows: the energy balance closes by construction, and the
tests check it numerically.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trainclimate.sim.params import AIR_CP_J_KG_K, STEFAN_BOLTZMANN, CoachParams

N_STATES = 9
ROOM, INV, CHASSIS = slice(0, 3), slice(3, 6), slice(6, 9)
STATE_NAMES = tuple(
    f"t_{part}_{deck}_c" for part in ("room", "inv", "chassis") for deck in ("up", "mid", "low")
)
KELVIN = 273.15

#: Internal flows: name → (node receiving +Q, node giving it). Q = UA · (T_giver − T_receiver).
INTERNAL_LINKS = (
    ("conv_room_up_mid", 0, 1),
    ("conv_room_mid_low", 1, 2),
    ("conv_room_inv_up", 0, 3),
    ("conv_room_inv_mid", 1, 4),
    ("conv_room_inv_low", 2, 5),
    ("conv_room_chassis_up_up", 0, 6),
    ("conv_room_chassis_up_mid", 0, 7),
    ("conv_room_chassis_mid_up", 1, 6),
    ("conv_room_chassis_mid_low", 1, 8),
    ("conv_room_chassis_low_mid", 2, 7),
    ("conv_room_chassis_low_low", 2, 8),
    ("cond_chassis_up_mid", 6, 7),
    ("cond_chassis_mid_low", 7, 8),
    ("cond_chassis_up_low", 6, 8),
)
#: External flows: name → node they enter.
EXTERNAL_FLOWS = (
    ("input_room_up", 0),
    ("input_room_mid", 1),
    ("input_room_low", 2),
    ("input_chassis_up", 6),
    ("input_chassis_mid", 7),
    ("input_chassis_low", 8),
    ("conv_env_chassis_up", 6),
    ("conv_env_chassis_low", 8),
    ("solar_roof", 6),
    ("solar_side_chassis_up", 6),
    ("solar_side_chassis_low", 8),
    ("solar_window_up", 0),
    ("solar_window_mid", 1),
    ("solar_window_low", 2),
    ("ground_radiation", 8),
    ("occupancy_up", 0),
    ("occupancy_mid", 1),
    ("occupancy_low", 2),
    ("door", 2),
    ("ventilation_up", 0),
    ("ventilation_mid", 1),
    ("ventilation_low", 2),
)
FLOW_NAMES = tuple(name for name, *_ in INTERNAL_LINKS) + tuple(n for n, _ in EXTERNAL_FLOWS)


def _incidence() -> np.ndarray:
    """(n_flows, 9) matrix adding each flow (W) into the node(s) it enters or leaves."""
    m = np.zeros((len(FLOW_NAMES), N_STATES))
    for k, (_, to, frm) in enumerate(INTERNAL_LINKS):
        m[k, to] += 1.0
        m[k, frm] -= 1.0
    for k, (_, node) in enumerate(EXTERNAL_FLOWS, start=len(INTERNAL_LINKS)):
        m[k, node] = 1.0
    return m


INCIDENCE = _incidence()
N_INTERNAL = len(INTERNAL_LINKS)


def h_ext_w_m2_k(speed_kmh: np.ndarray) -> np.ndarray:
    """Outer convective heat-transfer coefficient of the car body.

    McAdams' wind correlation: ``h = 5.7 + 3.8 v`` for v ≤ 5 m/s and ``h = 7.2 v^0.78`` above,
    with v the air speed over the surface in m/s (here the train speed, no wind). The paper only
    states that the coefficient depends on the speed (Section II.C.2).

    Parameters
    ----------
    speed_kmh : array-like
        Train speed; its sign is ignored. [km/h]

    Returns
    -------
    numpy.ndarray
        h, same shape as ``speed_kmh``. [W/(m² K)]

    References
    ----------
    .. [1] J. A. Duffie and W. A. Beckman, Solar Engineering of Thermal Processes,
       Eq. 3.15.1 ff.
    """
    v = np.abs(np.asarray(speed_kmh, dtype=float)) / 3.6
    return np.where(v <= 5.0, 5.7 + 3.8 * v, 7.2 * np.power(np.maximum(v, 5.0), 0.78))


def ground_temperature_c(t_amb_c: np.ndarray, params: CoachParams) -> np.ndarray:
    """Track (ballast) temperature T_G as a function of T_amb.

    ASSUMPTION (documented in docs/model.md): T_G = T_amb + s · (T_amb − T_threshold) above the
    threshold, i.e. a sun-heated ballast ~12 K above a 32 °C afternoon for the default s = 1.

    Parameters
    ----------
    t_amb_c : numpy.ndarray
        Ambient temperature. [°C]
    params : CoachParams
        Gives s (``ground_slope``) and T_threshold (``ground_threshold_c``).

    Returns
    -------
    numpy.ndarray
        T_G, same shape as ``t_amb_c``; equal to T_amb at or below the threshold. [°C]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.C.5.
    """
    excess = np.maximum(np.asarray(t_amb_c) - params.ground_threshold_c, 0.0)
    return t_amb_c + params.ground_slope * excess


@dataclass
class Drivers:
    """Everything that drives the coach block during one step, for N coaches.

    Attributes
    ----------
    q_act_w : numpy.ndarray of shape (N, 6)
        Q_act = Λ Q_in into the rooms and chassis parts up, mid, low. [W]
    t_amb_c : numpy.ndarray of shape (N,)
        Ambient temperature. [°C]
    speed_kmh : numpy.ndarray of shape (N,)
        Train speed. [km/h]
    q_roof_w_m2, q_side_w_m2 : numpy.ndarray of shape (N,)
        Roof and side solar projections Q_Gt, Q_Gs. [W/m²]
    passengers : numpy.ndarray of shape (N, 3)
        Passengers per deck.
    door_open : numpy.ndarray of shape (N,)
        Fraction of the step the lower-deck door is open, 0…1. [–]
    fresh_air_kg_s : numpy.ndarray of shape (N, 3)
        Outside air supplied to each deck. [kg/s]
    """

    q_act_w: np.ndarray
    t_amb_c: np.ndarray
    speed_kmh: np.ndarray
    q_roof_w_m2: np.ndarray
    q_side_w_m2: np.ndarray
    passengers: np.ndarray
    door_open: np.ndarray
    fresh_air_kg_s: np.ndarray


def capacities(params: CoachParams) -> np.ndarray:
    """Heat capacities m_p^d c_p^d of the nine nodes (Eq. (1)).

    Parameters
    ----------
    params : CoachParams
        One coach's, or stacked, parameters.

    Returns
    -------
    numpy.ndarray of shape (..., 9)
        Capacities in :data:`STATE_NAMES` order (rooms, inventory, chassis). [J/K]
    """
    return np.concatenate([params.c_room_j_k, params.c_inv_j_k, params.c_chassis_j_k], axis=-1)


def _link_conductances(p: CoachParams) -> np.ndarray:
    """UA (W/K) of every internal link in :data:`INTERNAL_LINKS` order, (N, 14)."""
    rc = p.ua_room_chassis_w_k
    return np.concatenate(
        [
            p.ua_deck_deck_w_k,
            p.ua_room_inv_w_k,
            rc[:, [0, 0, 1, 1, 2, 2], [0, 1, 0, 2, 1, 2]],
            p.ua_chassis_chassis_w_k,
        ],
        axis=1,
    )


_RECEIVER = np.array([link[1] for link in INTERNAL_LINKS])
_GIVER = np.array([link[2] for link in INTERNAL_LINKS])
_COL = {name: j for j, name in enumerate(FLOW_NAMES)}


def held_flows(drv: Drivers, p: CoachParams) -> np.ndarray:
    """The heat flows that do not depend on the temperatures, constant over a step.

    Parameters
    ----------
    drv : Drivers
        The step's drivers.
    p : CoachParams
        Parameters stacked over the N coaches.

    Returns
    -------
    numpy.ndarray of shape (N, len(FLOW_NAMES))
        Inputs Q_act, solar gains and passengers in their :data:`FLOW_NAMES` columns, zeros
        elsewhere. [W]
    """
    out = np.zeros((drv.t_amb_c.shape[0], len(FLOW_NAMES)))
    c = _COL
    out[:, c["input_room_up"] : c["input_chassis_low"] + 1] = drv.q_act_w
    out[:, c["solar_roof"]] = p.roof_absorptance * p.roof_area_m2 * drv.q_roof_w_m2
    side = drv.q_side_w_m2[:, None]
    out[:, c["solar_side_chassis_up"] : c["solar_side_chassis_low"] + 1] = (
        p.side_absorptance[:, None] * p.side_area_m2 * side
    )
    out[:, c["solar_window_up"] : c["solar_window_low"] + 1] = (
        p.window_g[:, None] * p.window_area_m2 * side
    )
    out[:, c["occupancy_up"] : c["occupancy_low"] + 1] = (
        p.heat_per_passenger_w[:, None] * drv.passengers
    )
    return out


def heat_flows(
    T: np.ndarray, drv: Drivers, p: CoachParams, held: np.ndarray | None = None
) -> np.ndarray:
    """Every heat flow of the coach block (Section II.C.1–7).

    Parameters
    ----------
    T : numpy.ndarray of shape (N, 9)
        Node temperatures in :data:`STATE_NAMES` order. [°C]
    drv : Drivers
        The step's drivers.
    p : CoachParams
        Parameters stacked over the N coaches.
    held : numpy.ndarray of shape (N, len(FLOW_NAMES)), optional
        The result of :func:`held_flows` for these drivers, when already computed. [W]

    Returns
    -------
    numpy.ndarray of shape (N, len(FLOW_NAMES))
        Heat flows in :data:`FLOW_NAMES` order; internal flows are positive into their
        receiving node (:data:`INTERNAL_LINKS`). [W]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.C.
    """
    out = held_flows(drv, p) if held is None else held.copy()
    c = _COL
    t_amb = drv.t_amb_c
    # internal: convection between decks, deck–inventory, deck–chassis, chassis conduction
    out[:, :N_INTERNAL] = _link_conductances(p) * (T[:, _GIVER] - T[:, _RECEIVER])
    # chassis ↔ environment with the speed-dependent coefficient
    h = h_ext_w_m2_k(drv.speed_kmh)[:, None]
    out[:, [c["conv_env_chassis_up"], c["conv_env_chassis_low"]]] = (
        h * p.area_ext_m2 * (t_amb[:, None] - T[:, [6, 8]])
    )
    # ground radiation (Stefan–Boltzmann), only when T_amb exceeds the threshold
    t_g = ground_temperature_c(t_amb, p) + KELVIN
    out[:, c["ground_radiation"]] = np.where(
        t_amb > p.ground_threshold_c,
        p.ground_emissivity * STEFAN_BOLTZMANN * p.ground_area_m2
        * (t_g**4 - (T[:, 8] + KELVIN) ** 4),
        0.0,
    )  # fmt: skip
    # lower-deck door and ventilation with outside air
    out[:, c["door"]] = drv.door_open * p.door_mass_flow_kg_s * AIR_CP_J_KG_K * (t_amb - T[:, 2])
    out[:, c["ventilation_up"] : c["ventilation_low"] + 1] = (
        drv.fresh_air_kg_s * AIR_CP_J_KG_K * (t_amb[:, None] - T[:, ROOM])
    )
    return out


def derivative(T: np.ndarray, drv: Drivers, p: CoachParams, inv_cap: np.ndarray) -> np.ndarray:
    """Rate of change of the nine temperatures, Eq. (1) for every node.

    Parameters
    ----------
    T : numpy.ndarray of shape (N, 9)
        Node temperatures. [°C]
    drv : Drivers
        The drivers.
    p : CoachParams
        Parameters stacked over the N coaches.
    inv_cap : numpy.ndarray of shape (N, 9)
        1 / :func:`capacities`. [K/J]

    Returns
    -------
    numpy.ndarray of shape (N, 9)
        dT/dt. [K/s]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Eq. (1).
    """
    return (heat_flows(T, drv, p) @ INCIDENCE) * inv_cap


def rk4_step(
    T: np.ndarray, drv: Drivers, p: CoachParams, inv_cap: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Advance the nine temperatures by one step with the drivers held (classical RK4).

    Parameters
    ----------
    T : numpy.ndarray of shape (N, 9)
        Node temperatures at the start of the step. [°C]
    drv : Drivers
        The drivers, held over the step.
    p : CoachParams
        Parameters stacked over the N coaches.
    inv_cap : numpy.ndarray of shape (N, 9)
        1 / :func:`capacities`. [K/J]
    dt_s : float
        Step length. [s]

    Returns
    -------
    T_next : numpy.ndarray of shape (N, 9)
        Node temperatures at the end of the step. [°C]
    mean_flows : numpy.ndarray of shape (N, len(FLOW_NAMES))
        Step-mean heat flows, weighted like the RK4 update so that Σ C·ΔT = dt · Σ(external mean
        flows) holds to round-off. [W]
    """
    held = held_flows(drv, p)
    f1 = heat_flows(T, drv, p, held)
    k1 = (f1 @ INCIDENCE) * inv_cap
    f2 = heat_flows(T + 0.5 * dt_s * k1, drv, p, held)
    k2 = (f2 @ INCIDENCE) * inv_cap
    f3 = heat_flows(T + 0.5 * dt_s * k2, drv, p, held)
    k3 = (f3 @ INCIDENCE) * inv_cap
    f4 = heat_flows(T + dt_s * k3, drv, p, held)
    mean_flows = (f1 + 2.0 * f2 + 2.0 * f3 + f4) / 6.0
    return T + dt_s * (mean_flows @ INCIDENCE) * inv_cap, mean_flows
