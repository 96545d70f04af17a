"""Activated against deactivated: energy per 30-minute window, savings, exclusions and comfort.

The maths of the paper's Section V and Table II, on plain series, so the experiment reports and
the service's pair-comparison API compute the same numbers from simulated or stored data:

- the energy of each coach per window (default 30 min) from its electrical power;
- the savings per window, 100 (1 − E_act / E_deact), undefined (None) in a window where the
  deactivated coach used no energy, and overall over the counted windows;
- windows where either coach was affected — connection lost, commands overwritten, data missing —
  are excluded, and their minutes reported (the paper excluded the intervals affected by its
  connection losses and communication errors);
- the average hourly constraint violation in K (paper, Table II): the time integral of
  max(0, |T_room − T_rule| − T_max) per deck, in K·h, divided by the hours counted, averaged over
  the decks — for both coaches, over the time the comfort band applies (regular mode) — and the
  BOPTEST-style thermal discomfort in K·h per deck.

Savings are counted from ``start`` (the time the activated coach reaches steady state) to ``end``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from trainclimate.analysis.kpi import discomfort_kh
from trainclimate.coach.setpoint import COMFORT_BAND_K


@dataclass
class CoachSeries:
    """One coach's series on a uniform UTC grid of n samples.

    Attributes
    ----------
    time : pandas.DatetimeIndex
        Timezone-aware times, shape (n,).
    power_kw : numpy.ndarray of shape (n,)
        The HVAC's electrical power, each sample the mean over its step; NaN where no data.
        [kW]
    t_room_c : numpy.ndarray of shape (n, 3)
        Deck temperatures up, mid, low. [°C]
    t_rule_c : numpy.ndarray of shape (n,)
        T_rule. [°C]
    affected : numpy.ndarray of bool, shape (n,)
        Where the connection was lost or commands were overwritten; samples with NaN power are
        added on construction.
    in_band : numpy.ndarray of bool, shape (n,)
        Where the comfort band applies — regular mode; a coach in slumber or off has none
        (default: everywhere).

    Raises
    ------
    ValueError
        If a series does not have the length of ``time``.
    """

    time: pd.DatetimeIndex
    power_kw: np.ndarray
    t_room_c: np.ndarray
    t_rule_c: np.ndarray
    affected: np.ndarray
    in_band: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.time)
        self.power_kw = np.asarray(self.power_kw, dtype=float)
        self.t_room_c = np.asarray(self.t_room_c, dtype=float).reshape(n, 3)
        self.t_rule_c = np.asarray(self.t_rule_c, dtype=float)
        self.affected = np.asarray(self.affected, dtype=bool)
        self.in_band = np.ones(n, bool) if self.in_band is None else np.asarray(self.in_band, bool)
        shapes = {a.shape for a in (self.power_kw, self.t_rule_c, self.affected, self.in_band)}
        if shapes != {(n,)}:
            raise ValueError("a coach's series must all have the length of its time axis")
        self.affected = self.affected | ~np.isfinite(self.power_kw)


@dataclass
class PairTotals:
    """What a pair's savings and comfort over a period are computed from, and what pools over
    trains: a fleet's totals are the sum of its pairs' (``+``).

    Attributes
    ----------
    energy_activated_kwh, energy_deactivated_kwh : float
        Energy of each coach over the included windows. [kWh]
    windows, excluded_windows : int
        Windows in the period, and those excluded (affected, or not covered by the series).
    window_min : float
        Window length. [min]
    counted_hours : float
        Time counted for violation and discomfort (both coaches in band, nothing affected). [h]
    discomfort_kh, baseline_discomfort_kh : numpy.ndarray of shape (3,)
        Discomfort per deck of the activated and the deactivated coach. [K·h]
    """

    energy_activated_kwh: float
    energy_deactivated_kwh: float
    windows: int
    excluded_windows: int
    window_min: float
    counted_hours: float
    discomfort_kh: np.ndarray
    baseline_discomfort_kh: np.ndarray

    @property
    def savings_pct(self) -> float | None:
        """Savings over the included windows, 100 (1 − E_act / E_deact) [%]; None when the
        deactivated coach used no energy in them."""
        return savings_pct(self.energy_activated_kwh, self.energy_deactivated_kwh)

    @property
    def excluded_minutes(self) -> float:
        """Length of the excluded windows. [min]"""
        return self.excluded_windows * self.window_min

    @property
    def avg_hourly_violation_k(self) -> float:
        """The activated coach's average hourly violation (Table II); 0 when nothing was
        counted. [K]"""
        return _per_hour(self.discomfort_kh, self.counted_hours)

    @property
    def baseline_violation_k(self) -> float:
        """The deactivated coach's average hourly violation; 0 when nothing was counted. [K]"""
        return _per_hour(self.baseline_discomfort_kh, self.counted_hours)

    def __add__(self, other: PairTotals) -> PairTotals:
        """Pooled: energies, windows, counted hours and discomfort added (same window length).

        Raises
        ------
        ValueError
            If the window lengths differ.
        """
        if other.window_min != self.window_min:
            raise ValueError("totals of different window lengths do not add up")
        return PairTotals(
            energy_activated_kwh=self.energy_activated_kwh + other.energy_activated_kwh,
            energy_deactivated_kwh=self.energy_deactivated_kwh + other.energy_deactivated_kwh,
            windows=self.windows + other.windows,
            excluded_windows=self.excluded_windows + other.excluded_windows,
            window_min=self.window_min,
            counted_hours=self.counted_hours + other.counted_hours,
            discomfort_kh=self.discomfort_kh + other.discomfort_kh,
            baseline_discomfort_kh=self.baseline_discomfort_kh + other.baseline_discomfort_kh,
        )

    @classmethod
    def empty(cls, window_min: float = 30.0) -> PairTotals:
        """No window, nothing counted: the start of a sum."""
        return cls(0.0, 0.0, 0, 0, window_min, 0.0, np.zeros(3), np.zeros(3))

    @classmethod
    def pooled(cls, parts: list[PairTotals], window_min: float = 30.0) -> PairTotals:
        """``empty(window_min) + parts[0] + parts[1] + …``, to the bit (each figure added in
        the parts' order), without an object per step (a fleet summary pools 450 trains).

        Raises
        ------
        ValueError
            If a part's window length is not ``window_min``.
        """
        if any(p.window_min != window_min for p in parts):
            raise ValueError("totals of different window lengths do not add up")
        e_act = e_deact = hours = 0.0
        windows = excluded = 0
        for p in parts:
            e_act += p.energy_activated_kwh
            e_deact += p.energy_deactivated_kwh
            windows += p.windows
            excluded += p.excluded_windows
            hours += p.counted_hours
        # numpy adds the rows of a reduction over its first axis one after the other
        zero = np.zeros((1, 3))
        discomfort = np.add.reduce(np.concatenate([zero, *(p.discomfort_kh[None] for p in parts)]))
        baseline = np.add.reduce(
            np.concatenate([zero, *(p.baseline_discomfort_kh[None] for p in parts)])
        )
        return cls(e_act, e_deact, windows, excluded, window_min, hours, discomfort, baseline)


def _per_hour(discomfort_kh: np.ndarray, hours: float) -> float:
    """Discomfort per deck (K·h) divided by the hours counted, averaged over the decks (paper,
    Table II: the average hourly violation) [K]; 0 when no time was counted."""
    # numpy.mean's sum and division, without its checks (this runs for every train of a summary)
    return float(discomfort_kh.sum() / discomfort_kh.size / hours) if hours > 0 else 0.0


@dataclass
class Comparison:
    """The result of :func:`compare` (JSON-ready through :meth:`to_dict`).

    Attributes
    ----------
    window_start : pandas.DatetimeIndex
        Start of each window, shape (W,).
    energy_activated_kwh, energy_deactivated_kwh : numpy.ndarray of shape (W,)
        Energy of each coach per window. [kWh]
    savings_30min_pct : list of float or None
        Savings per window, None where excluded or undefined. [%]
    excluded : numpy.ndarray of bool, shape (W,)
        Windows excluded (affected, or not covered by the series).
    savings_pct : float or None
        Savings over the included windows. [%]
    energy_activated_total_kwh, energy_deactivated_total_kwh : float
        Energy over the included windows. [kWh]
    excluded_minutes, affected_minutes : float
        Length of the excluded windows and of the affected samples. [min]
    counted_hours : float
        Time counted for violation and discomfort. [h]
    avg_hourly_violation_k, baseline_violation_k : float
        Average hourly violation of the activated and the deactivated coach. [K]
    discomfort_kh, baseline_discomfort_kh : list of float
        Discomfort per deck of the activated and the deactivated coach. [K·h]
    window_min : float
        Window length. [min]
    """

    window_start: pd.DatetimeIndex
    energy_activated_kwh: np.ndarray
    energy_deactivated_kwh: np.ndarray
    savings_30min_pct: list[float | None]
    excluded: np.ndarray
    savings_pct: float | None
    energy_activated_total_kwh: float
    energy_deactivated_total_kwh: float
    excluded_minutes: float
    affected_minutes: float
    counted_hours: float
    avg_hourly_violation_k: float
    baseline_violation_k: float
    discomfort_kh: list[float]
    baseline_discomfort_kh: list[float]
    window_min: float

    def to_dict(self) -> dict:
        """The comparison as a JSON-ready dict.

        Returns
        -------
        dict
            The attributes (``excluded`` as ``excluded_windows``), times as ISO 8601 strings,
            arrays as lists, in the units of the attribute names.
        """
        return {
            "savings_pct": self.savings_pct,
            "savings_30min_pct": self.savings_30min_pct,
            "window_start": [t.isoformat() for t in self.window_start],
            "window_min": self.window_min,
            "energy_activated_kwh": self.energy_activated_kwh.tolist(),
            "energy_deactivated_kwh": self.energy_deactivated_kwh.tolist(),
            "excluded_windows": self.excluded.tolist(),
            "energy_activated_total_kwh": self.energy_activated_total_kwh,
            "energy_deactivated_total_kwh": self.energy_deactivated_total_kwh,
            "excluded_minutes": self.excluded_minutes,
            "affected_minutes": self.affected_minutes,
            "counted_hours": self.counted_hours,
            "avg_hourly_violation_k": self.avg_hourly_violation_k,
            "baseline_violation_k": self.baseline_violation_k,
            "discomfort_kh": self.discomfort_kh,
            "baseline_discomfort_kh": self.baseline_discomfort_kh,
        }


def savings_pct(e_activated_kwh: float, e_deactivated_kwh: float) -> float | None:
    """Energy savings of the activated coach, 100 (1 − E_act / E_deact).

    Parameters
    ----------
    e_activated_kwh, e_deactivated_kwh : float
        Energy of the activated and the deactivated coach. [kWh]

    Returns
    -------
    float or None
        Savings [%]; None when the deactivated coach used no energy.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section V, Table II.
    """
    if not e_deactivated_kwh > 0:
        return None
    return float(100.0 * (1.0 - e_activated_kwh / e_deactivated_kwh))


def _step_s(time: pd.DatetimeIndex) -> float:
    if len(time) < 2:
        raise ValueError("a series needs at least two samples")
    steps = np.diff(time.as_unit("ns").asi8)
    if np.ptp(steps) != 0:
        raise ValueError("the series must be on a uniform time grid")
    return float(steps[0]) / 1e9


def compare(
    activated: CoachSeries,
    deactivated: CoachSeries,
    *,
    start: pd.Timestamp | None = None,
    end: pd.Timestamp | None = None,
    window_min: float = 30.0,
    t_max_k: float = COMFORT_BAND_K,
) -> Comparison:
    """Energy per window, savings and comfort of an activated/deactivated pair.

    Windows of ``window_min`` start at ``start`` and the last incomplete one is dropped; a window
    with an affected sample, or one the series do not cover entirely (``start`` before the first
    sample, ``end`` after the last), is excluded. Violation and discomfort count the same period,
    minus affected samples, where both coaches are in band. See the module docstring.

    Parameters
    ----------
    activated, deactivated : CoachSeries
        The two coaches, on one time grid.
    start : pandas.Timestamp, optional
        Start of the counted period, when the activated coach is in steady state (default:
        the first sample).
    end : pandas.Timestamp, optional
        End of the counted period (default: the end of the last sample's step).
    window_min : float, default 30.0
        Window length. [min]
    t_max_k : float, default COMFORT_BAND_K
        Comfort half-band T_max. [K]

    Returns
    -------
    Comparison

    Raises
    ------
    ValueError
        If the two series do not share one uniform time grid of at least two samples.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section V, Table II.
    """
    time = activated.time
    if len(deactivated.time) != len(time) or not (deactivated.time == time).all():
        raise ValueError("the two coaches' series must share one time grid")
    dt = _step_s(time)
    start = time[0] if start is None else pd.Timestamp(start)
    end = time[-1] + pd.Timedelta(seconds=dt) if end is None else pd.Timestamp(end)
    rel = (time - start).total_seconds().to_numpy()
    window_s = window_min * 60.0
    n_windows = int(max(0.0, (end - start).total_seconds()) // window_s)
    counted = (rel >= 0) & (rel < n_windows * window_s)
    index = np.where(counted, (rel // window_s).astype(int), -1)

    def per_window(values: np.ndarray) -> np.ndarray:
        out = np.zeros(n_windows)
        np.add.at(out, index[counted], values[counted])
        return out

    e_act = per_window(np.nan_to_num(activated.power_kw) * dt / 3600.0)
    e_deact = per_window(np.nan_to_num(deactivated.power_kw) * dt / 3600.0)
    affected = activated.affected | deactivated.affected
    # a window the series do not cover entirely has data missing, like an affected one
    first, stop = time[0], time[-1] + pd.Timedelta(seconds=dt)
    w_start = start + pd.to_timedelta(np.arange(n_windows) * window_s, unit="s")
    uncovered = (w_start < first) | (w_start + pd.Timedelta(seconds=window_s) > stop)
    excluded = (per_window(affected.astype(float)) > 0) | uncovered
    per = [None if excluded[w] else savings_pct(e_act[w], e_deact[w]) for w in range(n_windows)]
    mask = counted & ~affected & activated.in_band & deactivated.in_band
    totals = PairTotals(
        energy_activated_kwh=float(e_act[~excluded].sum()),
        energy_deactivated_kwh=float(e_deact[~excluded].sum()),
        windows=n_windows,
        excluded_windows=int(excluded.sum()),
        window_min=window_min,
        counted_hours=float(mask.sum() * dt / 3600.0),
        discomfort_kh=discomfort_kh(
            activated.t_room_c, activated.t_rule_c, dt, t_max_k=t_max_k, mask=mask
        ),
        baseline_discomfort_kh=discomfort_kh(
            deactivated.t_room_c, deactivated.t_rule_c, dt, t_max_k=t_max_k, mask=mask
        ),
    )
    return Comparison(
        window_start=w_start,
        energy_activated_kwh=e_act,
        energy_deactivated_kwh=e_deact,
        savings_30min_pct=per,
        excluded=excluded,
        savings_pct=totals.savings_pct,
        energy_activated_total_kwh=totals.energy_activated_kwh,
        energy_deactivated_total_kwh=totals.energy_deactivated_kwh,
        excluded_minutes=totals.excluded_minutes,
        affected_minutes=float((counted & affected).sum() * dt / 60.0),
        counted_hours=totals.counted_hours,
        avg_hourly_violation_k=totals.avg_hourly_violation_k,
        baseline_violation_k=totals.baseline_violation_k,
        discomfort_kh=totals.discomfort_kh.tolist(),
        baseline_discomfort_kh=totals.baseline_discomfort_kh.tolist(),
        window_min=window_min,
    )
