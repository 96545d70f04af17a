"""Disturbance forecasts for the controller: d = [T_amb, Q_Gt, Q_Gs, P, V] over the horizon.

The DDPC layer needs d(t+1) … d(t+T) (paper, Section III.C: "assumed to be available through
forecasts"). Three forecasters with one interface, to measure how much the controller depends on
the forecast's quality:

- :class:`PerfectForecast`: the true future (from the scenario) — the paper's simulation study;
- :class:`PersistenceForecast`: the last measured sample held over the horizon;
- :class:`NoisyForecast`: the truth plus errors that grow with the lead time — an AR(1) process
  along the lead steps, e(k) = φ e(k−1) + σ ε(k), in the temperature and in the (relative)
  irradiance, the kind of error model BOPTEST's forecast-uncertainty scenarios use. Occupancy and
  speed come from the timetable and are taken as known.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

#: The truth: a function of (tick index, number of steps) → (steps, 5) disturbance samples,
#: row j the disturbance over [t+j, t+j+1).
Truth = Callable[[int, int], np.ndarray]


class Forecaster(ABC):
    """Produces d(t+1) … d(t+T), (T, 5), at a tick."""

    name = "base"

    @abstractmethod
    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        """The forecast at controller tick ``tick``; ``last_measured`` is the newest d sample."""


class PerfectForecast(Forecaster):
    """The true future disturbances."""

    name = "perfect"

    def __init__(self, truth: Truth):
        self.truth = truth

    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        return np.asarray(self.truth(tick + 1, horizon), dtype=float)


class PersistenceForecast(Forecaster):
    """Tomorrow is like now: the newest measured sample, held."""

    name = "persistence"

    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        return np.tile(np.asarray(last_measured, dtype=float), (horizon, 1))


class NoisyForecast(Forecaster):
    """The truth plus AR(1) errors along the lead time: ``temp_sigma_k`` (K) and ``temp_phi`` on
    T_amb, ``solar_sigma`` (relative) and ``solar_phi`` on both irradiance projections; seeded,
    a fresh error path at every tick (independent of earlier ticks)."""

    name = "noisy"

    def __init__(
        self,
        truth: Truth,
        *,
        seed: int = 0,
        temp_sigma_k: float = 0.5,
        temp_phi: float = 0.9,
        solar_sigma: float = 0.15,
        solar_phi: float = 0.9,
    ):
        self.truth = truth
        self.seed = seed
        self.temp = (temp_sigma_k, temp_phi)
        self.solar = (solar_sigma, solar_phi)

    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        d = np.array(self.truth(tick + 1, horizon), dtype=float)
        rng = np.random.default_rng([self.seed, tick])
        e_t = e_s = 0.0
        for k in range(horizon):
            e_t = self.temp[1] * e_t + self.temp[0] * rng.normal()
            e_s = self.solar[1] * e_s + self.solar[0] * rng.normal()
            d[k, 0] += e_t
            d[k, 1:3] = np.maximum(d[k, 1:3] * (1.0 + e_s), 0.0)
        return d


FORECASTS = ("perfect", "persistence", "noisy")
