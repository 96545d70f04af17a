"""What a fleet of half coaches lives through: the weather, the sun, speed, occupancy, doors and
the HVAC mode, per time step and coach — the input of the
:class:`~trainclimate.sim.simulator.FleetSimulator`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from trainclimate.sim.solar import roof_irradiance, side_irradiance

#: The (steps, coaches) series of an :class:`Environment`.
SERIES_FIELDS = (
    "t_amb_c", "ghi_w_m2", "zenith_deg", "azimuth_deg", "heading_deg", "speed_kmh",
    "occupancy_pct", "door_open", "mode",
)  # fmt: skip


@dataclass
class Environment:
    """The disturbances and the operation of N coaches on a uniform time grid of S steps.

    Series given as (S,) or (S, 1) are broadcast to (S, N); the solar projections are derived
    on construction.

    Attributes
    ----------
    time : pandas.DatetimeIndex
        Timezone-aware UTC times, shape (S,); its step is the simulator's.
    t_amb_c : numpy.ndarray of shape (S, N)
        Ambient temperature. [°C]
    ghi_w_m2 : numpy.ndarray of shape (S, N)
        Global horizontal irradiance. [W/m²]
    zenith_deg, azimuth_deg : numpy.ndarray of shape (S, N)
        Solar zenith and azimuth (clockwise from north). [°]
    heading_deg : numpy.ndarray of shape (S, N)
        Train heading, clockwise from north. [°]
    speed_kmh : numpy.ndarray of shape (S, N)
        Train speed. [km/h]
    occupancy_pct : numpy.ndarray of shape (S, N)
        Occupancy. [% of seats]
    door_open : numpy.ndarray of shape (S, N)
        Fraction of the step the lower-deck door is open, 0…1. [–]
    mode : numpy.ndarray of shape (S, N)
        HVAC mode, ``MODE_*`` of :mod:`trainclimate.coach.rule`.
    q_roof_w_m2, q_side_w_m2 : numpy.ndarray of shape (S, N)
        Derived roof and side irradiance Q_Gt, Q_Gs (:mod:`trainclimate.sim.solar`). [W/m²]

    Raises
    ------
    ValueError
        If ``time`` is not timezone-aware or a series does not have shape (S, coaches).
    """

    time: pd.DatetimeIndex
    t_amb_c: np.ndarray
    ghi_w_m2: np.ndarray
    zenith_deg: np.ndarray
    azimuth_deg: np.ndarray
    heading_deg: np.ndarray
    speed_kmh: np.ndarray
    occupancy_pct: np.ndarray
    door_open: np.ndarray
    mode: np.ndarray
    q_roof_w_m2: np.ndarray = field(init=False)
    q_side_w_m2: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        if self.time.tz is None:
            raise ValueError("environment time must be timezone-aware")
        s = len(self.time)
        for name in SERIES_FIELDS:
            value = np.asarray(getattr(self, name))
            if value.ndim == 1:
                value = value[:, None]
            if value.ndim != 2 or value.shape[0] != s:
                raise ValueError(f"environment field {name!r} must have shape (steps, coaches)")
            setattr(self, name, value)
        n = max(getattr(self, name).shape[1] for name in SERIES_FIELDS)
        for name in SERIES_FIELDS:
            setattr(self, name, np.broadcast_to(getattr(self, name), (s, n)))
        self.q_roof_w_m2 = roof_irradiance(self.ghi_w_m2, self.zenith_deg)
        self.q_side_w_m2 = side_irradiance(
            self.ghi_w_m2, self.zenith_deg, self.azimuth_deg, self.heading_deg
        )

    def coaches(self, index: list[int]) -> Environment:
        """The environment of some of the coaches.

        Parameters
        ----------
        index : list of int
            Coach columns to keep.

        Returns
        -------
        Environment
            Same time grid, ``len(index)`` coaches.
        """
        return Environment(
            time=self.time,
            **{name: np.ascontiguousarray(getattr(self, name)[:, index]) for name in SERIES_FIELDS},
        )

    @classmethod
    def of_operations(
        cls, times, t_amb_c, ghi_w_m2, sun: pd.DataFrame, operations: list, mode: np.ndarray
    ) -> Environment:
        """One weather and sun for every coach, each coach its own operation.

        Parameters
        ----------
        times : pandas.DatetimeIndex
            The grid (timezone-aware).
        t_amb_c, ghi_w_m2 : array-like of shape (S,)
            Ambient temperature (°C) and global horizontal irradiance (W/m²).
        sun : pandas.DataFrame
            ``zenith_deg`` and ``azimuth_deg`` on the grid (:func:`~trainclimate.sim.solar.
            solar_position`). [°]
        operations : list of OperationSeries
            One per coach (:mod:`trainclimate.sim.routes`): heading, speed, occupancy, doors.
        mode : numpy.ndarray of shape (S, N)
            The HVAC mode of each coach.

        Returns
        -------
        Environment
        """

        def col(name: str) -> np.ndarray:
            return np.column_stack([getattr(o, name) for o in operations])

        return cls(
            time=times,
            t_amb_c=np.asarray(t_amb_c)[:, None],
            ghi_w_m2=np.asarray(ghi_w_m2)[:, None],
            zenith_deg=sun["zenith_deg"].to_numpy()[:, None],
            azimuth_deg=sun["azimuth_deg"].to_numpy()[:, None],
            heading_deg=col("heading_deg"),
            speed_kmh=col("speed_kmh"),
            occupancy_pct=col("occupancy_pct"),
            door_open=col("doors_open").astype(float),
            mode=mode,
        )

    @classmethod
    def side_by_side(cls, envs: list[Environment]) -> Environment:
        """Join independent environments as the columns of one.

        Runs on different days are so simulated together as one vectorised fleet. The result
        keeps the first environment's ``time``: the simulator only uses the grid's step, so
        each column's own clock stays with whoever built it.

        Parameters
        ----------
        envs : list of Environment
            Environments of equal length and step.

        Returns
        -------
        Environment
            Their coaches side by side, in order.

        Raises
        ------
        ValueError
            If ``envs`` is empty or their lengths or steps differ.
        """
        if not envs:
            raise ValueError("need at least one environment")
        first = envs[0]
        for env in envs[1:]:
            if len(env.time) != len(first.time) or env.dt_s != first.dt_s:
                raise ValueError("environments side by side need the same length and step")
        return cls(
            time=first.time,
            **{name: np.hstack([getattr(e, name) for e in envs]) for name in SERIES_FIELDS},
        )

    @property
    def n_coaches(self) -> int:
        """Number of coaches N."""
        return self.t_amb_c.shape[1]

    @property
    def dt_s(self) -> float:
        """Step of the time grid. [s]"""
        return float((self.time[1] - self.time[0]).total_seconds())
