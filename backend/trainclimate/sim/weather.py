"""Weather at Swiss sites: a seeded generator by place and date, and measured CSV files.

Both give a :class:`Weather`: ambient temperature (°C) and global horizontal irradiance (W/m²) on
a UTC time grid, interpolated linearly onto the simulator's grid by :meth:`Weather.at`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from trainclimate.sim.solar import clear_sky_ghi

LOCAL_TZ = "Europe/Zurich"


class WeatherError(ValueError):
    """A weather file or request that cannot be used; the message names the problem."""


@dataclass(frozen=True)
class Site:
    """A place where trains run or stand.

    Attributes
    ----------
    name : str
        Display name.
    latitude_deg, longitude_deg : float
        Position, north and east positive. [°]
    altitude_m : float
        Altitude above sea level. [m]
    """

    name: str
    latitude_deg: float
    longitude_deg: float
    altitude_m: float


# Approximate coordinates from public maps (to ~0.005°).
SITES: dict[str, Site] = {
    "zurich": Site("Zürich HB", 47.3779, 8.5403, 408.0),
    "muelligen": Site("Mülligen AG", 47.456, 8.238, 350.0),
    "wiesendangen": Site("Wiesendangen", 47.522, 8.789, 470.0),
    "zug": Site("Zug", 47.1734, 8.5152, 425.0),
    "winterthur": Site("Winterthur", 47.4999, 8.7236, 440.0),
}

# Monthly mean temperature (°C) and mean diurnal range (K) at Zürich/Fluntern (556 m), rounded
# after the MeteoSwiss climate normals 1991–2020.
_MONTHLY_MEAN_C = np.array([0.9, 1.8, 5.5, 9.4, 13.6, 17.1, 19.1, 18.5, 14.4, 10.0, 4.9, 1.7])
_MONTHLY_RANGE_K = np.array([5.0, 6.5, 8.0, 9.5, 9.5, 10.0, 10.5, 10.0, 9.0, 7.0, 5.0, 4.5])
_FLUNTERN_ALT_M = 556.0
_LAPSE_K_PER_M = -0.0065


@dataclass(frozen=True)
class Weather:
    """Ambient temperature and global horizontal irradiance on a time grid.

    Attributes
    ----------
    time : pandas.DatetimeIndex
        Timezone-aware UTC times, strictly increasing (any sampling interval), n samples.
    t_amb_c : numpy.ndarray of shape (n,)
        Ambient temperature T_amb. [°C]
    ghi_w_m2 : numpy.ndarray of shape (n,)
        Global horizontal irradiance Q_G. [W/m²]
    """

    time: pd.DatetimeIndex
    t_amb_c: np.ndarray
    ghi_w_m2: np.ndarray

    @property
    def span_hours(self) -> float:
        """Time from the first to the last sample. [h]"""
        return float((self.time[-1] - self.time[0]).total_seconds() / 3600.0)

    def at(self, times: pd.DatetimeIndex) -> tuple[np.ndarray, np.ndarray]:
        """Both signals linearly interpolated at ``times``.

        Parameters
        ----------
        times : pandas.DatetimeIndex
            Timezone-aware times; up to one weather step outside the span the end values are
            held.

        Returns
        -------
        t_amb_c : numpy.ndarray of shape (len(times),)
            Ambient temperature. [°C]
        ghi_w_m2 : numpy.ndarray of shape (len(times),)
            Global horizontal irradiance. [W/m²]

        Raises
        ------
        ValueError
            If ``times`` reaches outside the weather's span by more than one of its steps.
        """
        x = times.tz_convert("UTC").as_unit("ns").asi8.astype(float)
        xp = self.time.as_unit("ns").asi8.astype(float)
        step = float(np.median(np.diff(xp))) if len(xp) > 1 else 0.0
        if x.min() < xp[0] - step or x.max() > xp[-1] + step:
            raise ValueError(
                f"weather covers {self.time[0]} … {self.time[-1]}, asked for "
                f"{times[0]} … {times[-1]}"
            )
        return np.interp(x, xp, self.t_amb_c), np.interp(x, xp, self.ghi_w_m2)


def _climatology(day_of_year: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean temperature (°C, at Fluntern) and diurnal range (K) for fractional days of year,
    interpolated periodically between mid-month values."""
    mid = (np.arange(12) + 0.5) * 365.25 / 12.0
    xp = np.concatenate([mid - 365.25, mid, mid + 365.25])
    mean = np.interp(day_of_year, xp, np.tile(_MONTHLY_MEAN_C, 3))
    rng = np.interp(day_of_year, xp, np.tile(_MONTHLY_RANGE_K, 3))
    return mean, rng


def _sunrise_local_hours(day_of_year: np.ndarray, latitude_deg: float) -> np.ndarray:
    """Local standard-time hour of sunrise (Cooper's declination; solar noon ≈ 12:26 CET at
    8.5° E), good to ~10 min — only used to place the daily temperature minimum."""
    decl = np.radians(23.45 * np.sin(np.radians(360.0 * (284 + day_of_year) / 365.0)))
    cos_ws = np.clip(-np.tan(np.radians(latitude_deg)) * np.tan(decl), -1.0, 1.0)
    half_day_h = np.degrees(np.arccos(cos_ws)) / 15.0
    return 12.43 - half_day_h


def generate_weather(
    site: Site,
    start: pd.Timestamp,
    end: pd.Timestamp,
    *,
    seed: int,
    step_s: float = 600.0,
    t_min_c: float | None = None,
    t_max_c: float | None = None,
    cloud_cover: float | None = None,
) -> Weather:
    """Seeded synthetic weather at a Swiss site.

    - Each local day has a minimum near sunrise and a maximum at 15:00 local time, joined by
      half-cosines (continuous across days). Minimum and maximum are ``t_min_c`` / ``t_max_c``
      when given, otherwise the Zürich climatology for the date (altitude-corrected with
      −6.5 K/km) plus a seeded AR(1) day-to-day anomaly (σ 3 K, lag-1 correlation 0.7), the
      diurnal range damped by clouds: range · (1 − 0.5 · daily mean cloud cover).
    - Cloud cover C ∈ [0, 1]: a seeded hourly AR(1) in logit space with ~6 h persistence, mean
      ``cloud_cover`` (default 0.65 in winter, 0.5 in summer).
    - GHI = clear-sky GHI (pvlib, Ineichen) · (1 − 0.75 C^3.4) (Kasten & Czeplak 1980).

    Parameters
    ----------
    site : Site
        Where (latitude, longitude and altitude; see :data:`SITES`).
    start, end : pandas.Timestamp
        Timezone-aware first and last time, inclusive.
    seed : int
        Seed of the anomalies and clouds; the same seed gives the same weather.
    step_s : float, default 600.0
        Sampling interval. [s]
    t_min_c, t_max_c : float, optional
        Daily minimum and maximum temperature (default: climatology plus anomaly). [°C]
    cloud_cover : float, optional
        Mean cloud cover C in [0, 1] (default: seasonal). [–]

    Returns
    -------
    Weather
        On a UTC grid from ``start`` with step ``step_s``.

    Raises
    ------
    ValueError
        If ``start`` or ``end`` is not timezone-aware, or ``end`` is not after ``start``.
    """
    start, end = pd.Timestamp(start), pd.Timestamp(end)
    if start.tz is None or end.tz is None:
        raise ValueError("start and end must be timezone-aware")
    if end <= start:
        raise ValueError("end must be after start")
    rng = np.random.default_rng(seed)
    times = pd.date_range(
        start.tz_convert("UTC"), end.tz_convert("UTC"), freq=pd.Timedelta(seconds=step_s)
    )
    local = times.tz_convert(LOCAL_TZ)

    # days (local) from the day before the start to the day after the end
    first_day = local[0].normalize() - pd.Timedelta(days=1)
    days = pd.date_range(first_day, local[-1].normalize() + pd.Timedelta(days=1), freq="D")
    doy = days.day_of_year.to_numpy().astype(float)
    n_days = len(days)

    # clouds: hourly logit-AR(1)
    hours = pd.date_range(days[0], days[-1] + pd.Timedelta(days=1), freq="h")
    season_mean = 0.5 + 0.15 * np.cos(2 * np.pi * (hours.day_of_year.to_numpy() - 15) / 365.25)
    mean_c = np.full(len(hours), cloud_cover) if cloud_cover is not None else season_mean
    mean_c = np.clip(mean_c, 0.02, 0.98)
    phi = np.exp(-1.0 / 6.0)
    z = np.empty(len(hours))
    z[0] = rng.normal()
    for i in range(1, len(hours)):
        z[i] = phi * z[i - 1] + np.sqrt(1 - phi**2) * rng.normal()
    cloud_h = 1.0 / (1.0 + np.exp(-(np.log(mean_c / (1 - mean_c)) + 1.2 * z)))
    daily_cloud = cloud_h[: n_days * 24].reshape(n_days, 24).mean(axis=1)

    # daily minima and maxima
    mean_clim, range_clim = _climatology(doy)
    mean_clim = mean_clim + _LAPSE_K_PER_M * (site.altitude_m - _FLUNTERN_ALT_M)
    anomaly = np.empty(n_days)
    anomaly[0] = rng.normal(0, 3.0)
    for i in range(1, n_days):
        anomaly[i] = 0.7 * anomaly[i - 1] + np.sqrt(1 - 0.7**2) * rng.normal(0, 3.0)
    day_range = range_clim * (1 - 0.5 * daily_cloud)
    t_lo = mean_clim + anomaly - day_range / 2 if t_min_c is None else np.full(n_days, t_min_c)
    t_hi = mean_clim + anomaly + day_range / 2 if t_max_c is None else np.full(n_days, t_max_c)
    if t_min_c is None and t_max_c is not None:
        t_lo = np.minimum(t_lo, t_hi - 1.0)
    if t_max_c is None and t_min_c is not None:
        t_hi = np.maximum(t_hi, t_lo + 1.0)

    # anchors: (sunrise, T_min), (15:00, T_max) per local day, in local standard time
    offset_h = np.array([d.utcoffset().total_seconds() / 3600.0 for d in days]) - 1.0
    rise = _sunrise_local_hours(doy, site.latitude_deg) + offset_h
    day_ns = days.tz_convert("UTC").as_unit("ns").asi8.astype(float)
    anchor_t = np.column_stack([day_ns + rise * 3.6e12, day_ns + 15.0 * 3.6e12]).ravel()
    anchor_v = np.column_stack([t_lo, t_hi]).ravel()
    x = times.as_unit("ns").asi8.astype(float)
    idx = np.clip(np.searchsorted(anchor_t, x, side="right") - 1, 0, len(anchor_t) - 2)
    frac = (x - anchor_t[idx]) / (anchor_t[idx + 1] - anchor_t[idx])
    t_amb = anchor_v[idx] + (anchor_v[idx + 1] - anchor_v[idx]) * (1 - np.cos(np.pi * frac)) / 2

    cloud = np.interp(x, hours.tz_convert("UTC").as_unit("ns").asi8.astype(float), cloud_h)
    ghi = clear_sky_ghi(times, site.latitude_deg, site.longitude_deg, site.altitude_m)
    ghi = np.clip(ghi * (1 - 0.75 * cloud**3.4), 0.0, None)
    return Weather(time=times, t_amb_c=t_amb, ghi_w_m2=ghi)


def load_weather_csv(path: str | Path) -> Weather:
    """Read a measured weather CSV file.

    Parameters
    ----------
    path : str or pathlib.Path
        CSV with columns ``time`` (ISO 8601 with UTC offset), ``t_amb_c`` (°C, within
        −60…60) and ``ghi_w_m2`` (W/m², within 0…1500); at least 2 rows, times strictly
        increasing, any sampling interval; extra columns are ignored.

    Returns
    -------
    Weather
        With times converted to UTC.

    Raises
    ------
    WeatherError
        With a one-line message naming the file, the problem and, where it applies, the
        1-based data row.
    """
    path = Path(path)
    try:
        frame = pd.read_csv(path, dtype=str, keep_default_na=False)
    except FileNotFoundError:
        raise WeatherError(f"weather file not found: {path}") from None
    except (OSError, pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as exc:
        raise WeatherError(
            f"weather file {path} is unreadable: {str(exc).splitlines()[0]}"
        ) from None
    for col in ("time", "t_amb_c", "ghi_w_m2"):
        if col not in frame.columns:
            raise WeatherError(f"weather file {path}: missing column {col!r}")
    if len(frame) < 2:
        raise WeatherError(f"weather file {path}: needs at least 2 rows, has {len(frame)}")
    stamps = []
    for i, text in enumerate(frame["time"], start=1):
        try:
            ts = pd.Timestamp(text.strip())
        except (ValueError, TypeError):
            raise WeatherError(f"weather file {path}: row {i}: unparseable time {text!r}") from None
        if ts is pd.NaT or pd.isna(ts):
            raise WeatherError(f"weather file {path}: row {i}: unparseable time {text!r}")
        if ts.tz is None:
            raise WeatherError(f"weather file {path}: row {i}: time {text!r} has no UTC offset")
        stamps.append(ts.tz_convert("UTC"))
    time = pd.DatetimeIndex(stamps)
    bad = np.flatnonzero(np.diff(time.asi8) <= 0)
    if bad.size:
        raise WeatherError(
            f"weather file {path}: row {bad[0] + 2}: time is not strictly increasing "
            "(non-monotonic or duplicated)"
        )
    values = {}
    for col, lo, hi in (("t_amb_c", -60.0, 60.0), ("ghi_w_m2", 0.0, 1500.0)):
        v = pd.to_numeric(frame[col].str.strip(), errors="coerce").to_numpy(dtype=float)
        nan = np.flatnonzero(np.isnan(v))
        if nan.size:
            raise WeatherError(f"weather file {path}: row {nan[0] + 1}: {col} is NaN or empty")
        out = np.flatnonzero((v < lo) | (v > hi))
        if out.size:
            raise WeatherError(
                f"weather file {path}: row {out[0] + 1}: {col} = {v[out[0]]:g} outside "
                f"[{lo:g}, {hi:g}]"
            )
        values[col] = v
    return Weather(time=time, t_amb_c=values["t_amb_c"], ghi_w_m2=values["ghi_w_m2"])


def write_weather_csv(weather: Weather, path: str | Path) -> None:
    """Write weather in the format :func:`load_weather_csv` reads.

    Parameters
    ----------
    weather : Weather
        What to write; times are written in UTC, ISO 8601.
    path : str or pathlib.Path
        Destination CSV file.
    """
    pd.DataFrame(
        {
            "time": [t.isoformat() for t in weather.time],
            "t_amb_c": weather.t_amb_c,
            "ghi_w_m2": weather.ghi_w_m2,
        }
    ).to_csv(path, index=False)
