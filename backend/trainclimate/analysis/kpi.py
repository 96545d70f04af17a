"""Comfort and energy KPIs (BOPTEST-style) computed from simulated or measured series.

The comfort band is T_rule ± T_max (paper, Eq. (4)); a deck violates it by
``max(0, |T_room − T_rule| − T_max)`` kelvin. Integrated over time that is the thermal discomfort in
K·h per deck; divided by the hours counted it is the paper's "average hourly violation" (Table II),
averaged over the three decks.
"""

from __future__ import annotations

import numpy as np

from trainclimate.coach.setpoint import COMFORT_BAND_K


def violation_k(
    t_room_c: np.ndarray, t_rule_c: np.ndarray, t_max_k: float = COMFORT_BAND_K
) -> np.ndarray:
    """Violation of the comfort band T_rule ± T_max, max(0, |T_room − T_rule| − T_max).

    Parameters
    ----------
    t_room_c : numpy.ndarray of shape (..., 3)
        Deck temperatures up, mid, low. [°C]
    t_rule_c : array-like of shape (...)
        T_rule, broadcast against ``t_room_c`` as (..., 1). [°C]
    t_max_k : float, default COMFORT_BAND_K
        Comfort half-band T_max. [K]

    Returns
    -------
    numpy.ndarray of shape (..., 3)
        Violation per deck. [K]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Eq. (4).
    """
    return np.maximum(np.abs(t_room_c - np.asarray(t_rule_c)[..., None]) - t_max_k, 0.0)


def discomfort_kh(
    t_room_c: np.ndarray,
    t_rule_c: np.ndarray,
    dt_s: float,
    *,
    t_max_k: float = COMFORT_BAND_K,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Thermal discomfort per deck: ∫ violation dt over the counted samples.

    Parameters
    ----------
    t_room_c : numpy.ndarray of shape (S, 3)
        Deck temperatures, sampled every ``dt_s``. [°C]
    t_rule_c : numpy.ndarray of shape (S,)
        T_rule. [°C]
    dt_s : float
        Sampling interval. [s]
    t_max_k : float, default COMFORT_BAND_K
        Comfort half-band T_max. [K]
    mask : numpy.ndarray of bool, shape (S,), optional
        The counted samples (default: all).

    Returns
    -------
    numpy.ndarray of shape (3,)
        Discomfort of the decks up, mid, low. [K·h]
    """
    v = violation_k(t_room_c, t_rule_c, t_max_k)
    if mask is not None:
        v = v[np.asarray(mask, dtype=bool)]
    return v.sum(axis=0) * dt_s / 3600.0


def avg_hourly_violation_k(
    t_room_c: np.ndarray,
    t_rule_c: np.ndarray,
    dt_s: float,
    *,
    t_max_k: float = COMFORT_BAND_K,
    mask: np.ndarray | None = None,
) -> float:
    """The paper's average hourly constraint violation (Table II).

    Discomfort (K·h) per deck divided by the hours counted, averaged over the decks.

    Parameters
    ----------
    t_room_c, t_rule_c, dt_s, t_max_k, mask
        As in :func:`discomfort_kh` (units °C, °C, s, K; ``mask`` selects the counted samples).

    Returns
    -------
    float
        Average hourly violation; 0 when no sample is counted. [K]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section V, Table II.
    """
    n = len(t_room_c) if mask is None else int(np.count_nonzero(mask))
    if n == 0:
        return 0.0
    hours = n * dt_s / 3600.0
    return float(discomfort_kh(t_room_c, t_rule_c, dt_s, t_max_k=t_max_k, mask=mask).mean() / hours)


def energy_kwh(power_kw: np.ndarray, dt_s: float, mask: np.ndarray | None = None) -> float:
    """Energy of a power series (rectangle rule: each sample is the mean power over its step).

    Parameters
    ----------
    power_kw : array-like of shape (S,)
        Power. [kW]
    dt_s : float
        Sampling interval. [s]
    mask : numpy.ndarray of bool, shape (S,), optional
        The counted samples (default: all).

    Returns
    -------
    float
        Energy. [kWh]
    """
    p = np.asarray(power_kw, dtype=float)
    if mask is not None:
        p = p[np.asarray(mask, dtype=bool)]
    return float(p.sum() * dt_s / 3600.0)
