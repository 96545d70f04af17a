"""Comfort and energy KPIs (BOPTEST-style) computed from simulated or measured series.

The comfort band is T_rule ± T_max (paper, Eq. (4)); a deck violates it by
``max(0, |T_room − T_rule| − T_max)`` kelvin. Integrated over time that is the thermal discomfort in
K·h per deck; divided by the hours counted it is the paper's "average hourly violation" (Table II),
averaged over the three decks.
"""

from __future__ import annotations

import numpy as np


def violation_k(t_room_c: np.ndarray, t_rule_c: np.ndarray, t_max_k: float = 1.0) -> np.ndarray:
    """Band violation in K, shape of ``t_room_c`` (..., 3); ``t_rule_c`` broadcasts as (..., 1)."""
    return np.maximum(np.abs(t_room_c - np.asarray(t_rule_c)[..., None]) - t_max_k, 0.0)


def discomfort_kh(
    t_room_c: np.ndarray,
    t_rule_c: np.ndarray,
    dt_s: float,
    *,
    t_max_k: float = 1.0,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Thermal discomfort per deck in K·h: ∫ violation dt over the samples in ``mask``.

    ``t_room_c`` (S, 3) °C sampled every ``dt_s`` seconds, ``t_rule_c`` (S,) °C, ``mask`` (S,)
    bool selecting the counted samples (default all). Returns (3,).
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
    t_max_k: float = 1.0,
    mask: np.ndarray | None = None,
) -> float:
    """The paper's average hourly constraint violation in K: discomfort (K·h) per deck divided
    by the hours counted, averaged over the decks. 0 when no sample is counted."""
    n = len(t_room_c) if mask is None else int(np.count_nonzero(mask))
    if n == 0:
        return 0.0
    hours = n * dt_s / 3600.0
    return float(discomfort_kh(t_room_c, t_rule_c, dt_s, t_max_k=t_max_k, mask=mask).mean() / hours)


def energy_kwh(power_kw: np.ndarray, dt_s: float, mask: np.ndarray | None = None) -> float:
    """Energy in kWh of a power series in kW sampled every ``dt_s`` s (rectangle rule: each
    sample is the mean power over its step)."""
    p = np.asarray(power_kw, dtype=float)
    if mask is not None:
        p = p[np.asarray(mask, dtype=bool)]
    return float(p.sum() * dt_s / 3600.0)
