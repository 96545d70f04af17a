"""Held-out validation of a twin: which of a coach's days are held out, the twin's errors on
them (in all and per band of ambient temperature), and the ambient range they validate it for
(docs/model.md, "Calibration").
"""

from __future__ import annotations

import datetime

import numpy as np

from trainclimate.data.trajectory import Trajectory
from trainclimate.twin.knobs import CalibrationError
from trainclimate.twin.replay import Replay

#: The share of days held out.
HOLDOUT_SHARE = 0.25
#: Width of the ambient-temperature bands the held-out errors are reported in (K), the fewest
#: scored minutes a band needs, and the energy error a band may have and be validated (%).
BAND_K, MIN_BAND_MINUTES, VALID_ENERGY_PCT = 5.0, 60, 5.0


def local_day(t: Trajectory) -> datetime.date:
    """The local (Europe/Zurich) date ``t`` starts on."""
    return t.time[0].tz_convert("Europe/Zurich").date()


def split_days(trajectories: list[Trajectory]) -> tuple[list[Trajectory], list[Trajectory]]:
    """Training and held-out trajectories, by the local date a trajectory starts on, held out
    by condition: of the coach's days ranked by their mean logged T_amb, the coldest, the
    warmest, the next coldest, … — ``round(HOLDOUT_SHARE · days)`` of them, at least one and,
    from 3 days on, at least two — so that the held-out days test the twin beyond the
    conditions it was fitted on."""
    days = sorted({local_day(t) for t in trajectories})
    if len(days) < 2:
        raise CalibrationError(
            f"calibration needs trajectories on at least 2 days (training and held out); "
            f"got {len(days)}"
        )
    warmth = {
        day: float(
            np.nanmean(np.concatenate([t.d[:, 0] for t in trajectories if local_day(t) == day]))
        )
        for day in days
    }
    ranked = sorted(days, key=lambda day: (warmth[day], day))
    count = max(1 if len(days) < 3 else 2, round(HOLDOUT_SHARE * len(days)))
    held = {ranked[k // 2] if k % 2 == 0 else ranked[-1 - k // 2] for k in range(count)}
    train = [t for t in trajectories if local_day(t) not in held]
    holdout = [t for t in trajectories if local_day(t) in held]
    return train, holdout


def errors(
    rep: Replay, y: np.ndarray, p: np.ndarray, minutes: np.ndarray | None = None
) -> dict[str, float | None]:
    """The twin's errors on the scored minutes (or on ``minutes``, a mask of them): deck
    temperature MAE (K), power MAE (kW) and the metered energy's relative error (%; minutes
    with a metered power only; None without any)."""
    scored = rep.scored if minutes is None else minutes
    power = scored & np.isfinite(rep.p_kw)
    logged = rep.p_kw[power].sum()
    return {
        "t_room_mae_c": float(np.abs(y - rep.y)[scored].mean()),
        "power_mae_kw": float(np.abs(p - rep.p_kw)[power].mean()) if power.any() else None,
        "energy_error_pct": (
            float(100.0 * (p[power].sum() - logged) / logged) if logged > 0 else None
        ),
        "minutes": int(scored.sum()),
    }


def t_amb_minutes(rep: Replay) -> np.ndarray:
    """The logged T_amb of each replayed minute (minutes, columns). [°C]"""
    return rep.env.t_amb_c[:: rep.per_minute][: len(rep.y)]


def band_errors(rep: Replay, y: np.ndarray, p: np.ndarray) -> list[dict]:
    """:func:`errors` per :data:`BAND_K`-wide band of the logged T_amb (``t_amb_c``: [low,
    high) in °C), of the bands with at least :data:`MIN_BAND_MINUTES` scored minutes."""
    band = np.floor(t_amb_minutes(rep) / BAND_K) * BAND_K
    out = []
    for low in np.unique(band[rep.scored]):
        mask = rep.scored & (band == low)
        if mask.sum() >= MIN_BAND_MINUTES:
            out.append({"t_amb_c": [float(low), float(low + BAND_K)], **errors(rep, y, p, mask)})
    return out


def validated_range(
    train_t_amb_c: np.ndarray, bands: list[dict]
) -> tuple[list[float] | None, list[str]]:
    """The ambient temperatures the twin is validated for, and warnings.

    The training minutes' T_amb (2nd to 98th percentile, ``train_t_amb_c`` in °C), widened by
    each held-out band (:func:`band_errors`) next to it whose energy error is within
    :data:`VALID_ENERGY_PCT`, outwards until one is not; a held-out band beyond that error
    is warned of and cut from the range on its side. None (and a warning) when nothing is left.
    """
    low, high = (float(v) for v in np.percentile(train_t_amb_c, [2, 98]))
    middle = (low + high) / 2

    def good(b: dict) -> bool:
        e = b["energy_error_pct"]
        return e is not None and abs(e) <= VALID_ENERGY_PCT

    warnings = [
        f"held out at {b['t_amb_c'][0]:g} to {b['t_amb_c'][1]:g} °C the twin's energy is "
        + ("not metered" if b["energy_error_pct"] is None else f"{b['energy_error_pct']:+.1f} %")
        + f" off (beyond ±{VALID_ENERGY_PCT:g} %): not validated there"
        for b in bands
        if not good(b)
    ]
    for b in sorted((b for b in bands if b["t_amb_c"][0] < low), key=lambda b: -b["t_amb_c"][0]):
        if not good(b) or b["t_amb_c"][1] < np.floor(low / BAND_K) * BAND_K:
            break
        low = b["t_amb_c"][0]
    for b in sorted((b for b in bands if b["t_amb_c"][1] > high), key=lambda b: b["t_amb_c"][0]):
        if not good(b) or b["t_amb_c"][0] > np.ceil(high / BAND_K) * BAND_K:
            break
        high = b["t_amb_c"][1]
    for b in bands:
        a, z = b["t_amb_c"]
        if not good(b) and a < high and z > low:
            if (a + z) / 2 < middle:
                low = max(low, z)
            else:
                high = min(high, a)
    if not low < high:
        return None, [*warnings, "the twin is validated at no ambient temperature"]
    return [round(low, 1), round(high, 1)], warnings
