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
    """Base of the disturbance forecasters: produces d(t+1) … d(t+T) at a tick.

    Attributes
    ----------
    name : str
        The forecaster's name, one of :data:`FORECASTS`.
    """

    name = "base"

    @abstractmethod
    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        """The forecast at a controller tick.

        Parameters
        ----------
        tick : int
            Controller tick index t.
        horizon : int
            Number of steps to forecast.
        last_measured : numpy.ndarray of shape (5,)
            The newest measured disturbance sample d = [T_amb °C, Q_Gt W/m², Q_Gs W/m², P % of
            seats, V km/h].

        Returns
        -------
        numpy.ndarray of shape (horizon, 5)
            d(t+1) … d(t+horizon), same columns and units as ``last_measured``.
        """


class PerfectForecast(Forecaster):
    """The true future disturbances (the paper's simulation study, Section IV.B).

    Parameters
    ----------
    truth : Truth
        (tick index, number of steps) → (steps, 5) true disturbance samples.
    """

    name = "perfect"

    def __init__(self, truth: Truth):
        self.truth = truth

    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        """The true d(t+1) … d(t+horizon); ``last_measured`` is ignored.

        Parameters and Returns as in :meth:`Forecaster.forecast`.
        """
        return np.asarray(self.truth(tick + 1, horizon), dtype=float)


class PersistenceForecast(Forecaster):
    """Tomorrow is like now: the newest measured sample, held."""

    name = "persistence"

    def forecast(self, tick: int, horizon: int, last_measured: np.ndarray) -> np.ndarray:
        """``last_measured`` repeated ``horizon`` times.

        Parameters and Returns as in :meth:`Forecaster.forecast`.
        """
        return np.tile(np.asarray(last_measured, dtype=float), (horizon, 1))


class NoisyForecast(Forecaster):
    """The truth plus AR(1) errors along the lead time, e(k) = φ e(k−1) + σ ε(k).

    Seeded; a fresh error path at every tick (independent of earlier ticks). Occupancy and
    speed are taken as known.

    Parameters
    ----------
    truth : Truth
        (tick index, number of steps) → (steps, 5) true disturbance samples.
    seed : int, default 0
        Seed of the errors (combined with the tick).
    temp_sigma_k : float, default 0.5
        σ of the additive error on T_amb. [K]
    temp_phi : float, default 0.9
        φ of the T_amb error. [–]
    solar_sigma : float, default 0.15
        σ of the relative error on both irradiance projections (clipped at zero). [–]
    solar_phi : float, default 0.9
        φ of the irradiance error. [–]
    """

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
        """The true d(t+1) … d(t+horizon) with the tick's error path; ``last_measured`` is
        ignored.

        Parameters and Returns as in :meth:`Forecaster.forecast`.
        """
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
