"""Where a train is, which way it points, how fast it goes, when its doors open, how full it is.

Real Zurich S-Bahn lines served by Regio-Dosto trains (station coordinates approximate, from
public maps, to ~0.01°; station sequences simplified), a trapezoidal speed profile between
stations, seeded dwell times with door openings, turnarounds and layovers at the termini, and a
seeded occupancy per trip and leg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

EARTH_RADIUS_M = 6_371_000.0
LOCAL_TZ = "Europe/Zurich"
#: Acceleration and braking of a Regio-Dosto in service, m/s² (RABe 511: up to ~1.1 m/s²).
ACCEL_M_S2, BRAKE_M_S2 = 0.9, 0.8
#: Track length over great-circle distance between adjacent stations (assumption).
DETOUR = 1.15


@dataclass(frozen=True)
class Station:
    """A station on a line.

    Attributes
    ----------
    name : str
        Station name as on the timetable, e.g. ``"Zürich HB"``.
    latitude_deg, longitude_deg : float
        Position, north and east positive (approximate, ~0.01°). [°]
    """

    name: str
    latitude_deg: float
    longitude_deg: float


@dataclass(frozen=True)
class Line:
    """An S-Bahn line served by Regio-Dosto trains.

    Attributes
    ----------
    name : str
        Line name, e.g. ``"S12"``.
    stations : tuple of Station
        Stations from one terminus to the other (sequence simplified).
    v_max_kmh : float
        Maximum running speed. [km/h]
    """

    name: str
    stations: tuple[Station, ...]
    v_max_kmh: float


def _line(name: str, v_max: float, *stations: tuple[str, float, float]) -> Line:
    return Line(name, tuple(Station(*s) for s in stations), v_max)


ZURICH_HB = ("Zürich HB", 47.3779, 8.5403)
LINES: dict[str, Line] = {
    line.name: line
    for line in (
        _line(
            "S12",
            140.0,
            ("Brugg AG", 47.4807, 8.2089),
            ("Baden", 47.4762, 8.3077),
            ("Killwangen-Spreitenbach", 47.4330, 8.3503),
            ("Dietikon", 47.4055, 8.4000),
            ("Schlieren", 47.3990, 8.4477),
            ("Zürich Altstetten", 47.3914, 8.4889),
            ZURICH_HB,
            ("Zürich Stadelhofen", 47.3667, 8.5485),
            ("Stettbach", 47.3972, 8.5960),
            ("Dietlikon", 47.4226, 8.6190),
            ("Effretikon", 47.4258, 8.6865),
            ("Winterthur", 47.4999, 8.7236),
        ),
        _line(
            "S8",
            140.0,
            ("Winterthur", 47.4999, 8.7236),
            ("Effretikon", 47.4258, 8.6865),
            ("Wallisellen", 47.4120, 8.5926),
            ("Zürich Oerlikon", 47.4115, 8.5442),
            ("Zürich Hardbrücke", 47.3851, 8.5171),
            ZURICH_HB,
            ("Zürich Wiedikon", 47.3713, 8.5232),
            ("Thalwil", 47.2952, 8.5647),
            ("Horgen", 47.2600, 8.5975),
            ("Wädenswil", 47.2297, 8.6714),
            ("Pfäffikon SZ", 47.2014, 8.7787),
        ),
        _line(
            "S14",
            120.0,
            ZURICH_HB,
            ("Zürich Oerlikon", 47.4115, 8.5442),
            ("Wallisellen", 47.4120, 8.5926),
            ("Dübendorf", 47.3999, 8.6238),
            ("Schwerzenbach", 47.3822, 8.6569),
            ("Uster", 47.3505, 8.7178),
            ("Aathal", 47.3364, 8.7660),
            ("Wetzikon", 47.3225, 8.7975),
        ),
    )
}


def haversine_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Great-circle distance between two points (haversine formula).

    Parameters
    ----------
    lat1, lon1, lat2, lon2 : array-like
        Latitudes and longitudes of the two points, broadcastable. [°]

    Returns
    -------
    numpy.ndarray
        Distance on a sphere of radius :data:`EARTH_RADIUS_M`. [m]
    """
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dp, dl = p2 - p1, np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin(dp / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def bearing_deg(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Initial great-circle bearing from point 1 to point 2.

    Parameters
    ----------
    lat1, lon1, lat2, lon2 : array-like
        The two points, as in :func:`haversine_m`. [°]

    Returns
    -------
    numpy.ndarray
        Bearing clockwise from north in [0, 360), the convention of pvlib's solar azimuth. [°]
    """
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dl = np.radians(np.asarray(lon2) - np.asarray(lon1))
    y = np.sin(dl) * np.cos(p2)
    x = np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dl)
    return np.mod(np.degrees(np.arctan2(y, x)), 360.0)


def heading_from_positions(lat, lon, min_move_m: float = 1.0) -> np.ndarray:
    """The heading θ of a train from a sequence of its positions.

    Forward differences between successive positions; while the train does not move (less than
    ``min_move_m`` between samples) the last known heading is held, and samples before the first
    movement take the first movement's heading (0 if it never moves). The paper likewise computes
    the train's direction from its latitude and longitude (Section III.A).

    Parameters
    ----------
    lat, lon : array-like of shape (n,)
        Positions in time order. [°]
    min_move_m : float, default 1.0
        Smallest distance between samples that counts as movement. [m]

    Returns
    -------
    numpy.ndarray of shape (n,)
        Heading clockwise from north. [°]
    """
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    n = lat.size
    heading = np.full(n, np.nan)
    if n > 1:
        moved = haversine_m(lat[:-1], lon[:-1], lat[1:], lon[1:]) >= min_move_m
        b = bearing_deg(lat[:-1], lon[:-1], lat[1:], lon[1:])
        heading[:-1] = np.where(moved, b, np.nan)
    s = pd.Series(heading).ffill().bfill()
    return s.fillna(0.0).to_numpy()


@dataclass
class OperationSeries:
    """A train's operation on a uniform UTC grid; every array has ``len(time)`` entries.

    Attributes
    ----------
    time : pandas.DatetimeIndex
        Timezone-aware (UTC) uniform grid of n samples.
    latitude_deg, longitude_deg : numpy.ndarray of shape (n,)
        Position. [°]
    heading_deg : numpy.ndarray of shape (n,)
        Heading θ clockwise from north. [°]
    speed_kmh : numpy.ndarray of shape (n,)
        Speed. [km/h]
    doors_open : numpy.ndarray of bool, shape (n,)
        Whether the lower-deck doors are open.
    occupancy_pct : numpy.ndarray of shape (n,)
        Occupancy, 0–150. [% of seats]
    operation : numpy.ndarray of object, shape (n,)
        ``"service"``, ``"layover"`` or ``"parked"``.
    """

    time: pd.DatetimeIndex
    latitude_deg: np.ndarray
    longitude_deg: np.ndarray
    heading_deg: np.ndarray
    speed_kmh: np.ndarray
    doors_open: np.ndarray
    occupancy_pct: np.ndarray
    operation: np.ndarray

    def to_frame(self) -> pd.DataFrame:
        """The series as a DataFrame.

        Returns
        -------
        pandas.DataFrame
            Indexed by ``time``, one column per attribute (units as in the attribute names).
        """
        return pd.DataFrame(
            {
                k: getattr(self, k)
                for k in (
                    "latitude_deg",
                    "longitude_deg",
                    "heading_deg",
                    "speed_kmh",
                    "doors_open",
                    "occupancy_pct",
                    "operation",
                )
            },
            index=self.time,
        )


def _check_grid(times: pd.DatetimeIndex) -> None:
    if getattr(times, "tz", None) is None:
        raise ValueError("times must be timezone-aware")
    if len(times) > 2 and np.ptp(np.diff(times.asi8)) != 0:
        raise ValueError("times must be a uniform grid")


def stationary(
    times: pd.DatetimeIndex,
    *,
    latitude_deg: float,
    longitude_deg: float,
    heading_deg: float,
    operation: str = "service",
) -> OperationSeries:
    """A train standing still, doors closed and empty (the paper's parked experiments).

    Parameters
    ----------
    times : pandas.DatetimeIndex
        Timezone-aware uniform grid.
    latitude_deg, longitude_deg : float
        Where it stands. [°]
    heading_deg : float
        Which way it points, clockwise from north (taken modulo 360). [°]
    operation : str, default "service"
        Operation label for every sample.

    Returns
    -------
    OperationSeries
        Constant position and heading, zero speed and occupancy, doors closed.

    Raises
    ------
    ValueError
        If ``times`` is not timezone-aware or not uniform.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section V.
    """
    _check_grid(times)
    n = len(times)
    return OperationSeries(
        time=times,
        latitude_deg=np.full(n, latitude_deg),
        longitude_deg=np.full(n, longitude_deg),
        heading_deg=np.full(n, float(heading_deg) % 360.0),
        speed_kmh=np.zeros(n),
        doors_open=np.zeros(n, dtype=bool),
        occupancy_pct=np.zeros(n),
        operation=np.full(n, operation, dtype=object),
    )


def run_profile(length_m: float, v_max_kmh: float) -> tuple[float, float, float, float]:
    """Trapezoidal (or, on a short run, triangular) speed profile between two stations.

    Parameters
    ----------
    length_m : float
        Track length of the run. [m]
    v_max_kmh : float
        Line speed. [km/h]

    Returns
    -------
    v_peak : float
        Peak speed. [m/s]
    t_accel, t_cruise, t_brake : float
        Durations of acceleration, cruising and braking. [s]
    """
    v = v_max_kmh / 3.6
    if v**2 / (2 * ACCEL_M_S2) + v**2 / (2 * BRAKE_M_S2) > length_m:
        v = np.sqrt(2 * length_m * ACCEL_M_S2 * BRAKE_M_S2 / (ACCEL_M_S2 + BRAKE_M_S2))
    t_acc, t_brk = v / ACCEL_M_S2, v / BRAKE_M_S2
    cruise = (length_m - v**2 / (2 * ACCEL_M_S2) - v**2 / (2 * BRAKE_M_S2)) / v
    return float(v), float(t_acc), float(max(cruise, 0.0)), float(t_brk)


def _run_state(tau: np.ndarray, v: float, t_acc: float, t_cru: float, t_brk: float):
    """Speed (m/s) and distance covered (m) at times ``tau`` (s) into a run."""
    tau = np.clip(tau, 0.0, t_acc + t_cru + t_brk)
    d_acc = 0.5 * v * t_acc
    in_acc, in_cru = tau < t_acc, tau < t_acc + t_cru
    tb = tau - t_acc - t_cru
    speed = np.where(in_acc, ACCEL_M_S2 * tau, np.where(in_cru, v, v - BRAKE_M_S2 * tb))
    dist = np.where(
        in_acc,
        0.5 * ACCEL_M_S2 * tau**2,
        np.where(
            in_cru, d_acc + v * (tau - t_acc), d_acc + v * t_cru + v * tb - 0.5 * BRAKE_M_S2 * tb**2
        ),
    )
    return np.maximum(speed, 0.0), dist


def _occupancy(local_hour: float, towards_hb: bool, rng: np.random.Generator) -> float:
    """Seeded occupancy of one leg in % of seats: commuter peaks at ~07:45 and ~17:45, ~35 %
    at midday, ~15 % late; fuller towards Zürich HB in the morning and away from it at night."""
    h = local_hour
    base = (
        12
        + 65 * np.exp(-(((h - 7.75) / 0.9) ** 2))
        + 60 * np.exp(-(((h - 17.75) / 1.0) ** 2))
        + 22 * np.exp(-(((h - 12.5) / 2.5) ** 2))
    )
    morning = 5 <= h < 12
    tilt = 1.3 if towards_hb == morning else 0.7
    return float(np.clip(base * tilt * rng.lognormal(0.0, 0.15), 0.0, 150.0))


def service_day(
    line: Line,
    times: pd.DatetimeIndex,
    *,
    seed: int,
    first_departure: pd.Timestamp,
    last_arrival: pd.Timestamp,
    layovers=(),
    start_at_terminus: int = 0,
    preparation_min: float = 45.0,
) -> OperationSeries:
    """A train running back and forth on ``line`` all day (see the module docstring).

    Parked at its first terminus until ``preparation_min`` before ``first_departure`` (HVAC
    preparation: in service, stationary, doors closed, empty); trips until ``last_arrival`` (the
    trip under way is finished); at an intermediate station a seeded 30–60 s dwell with the
    doors open for all but 10 s of it; at a terminus an 8–15 min turnaround (doors open the first
    and last 2 min) or, if a ``layovers`` window (start, end) begins within 30 min, a layover
    until its end; parked after the last arrival. Occupancy is seeded per leg, with commuter
    peaks near 07:45 and 17:45 local time.

    Parameters
    ----------
    line : Line
        The line served.
    times : pandas.DatetimeIndex
        Timezone-aware uniform grid to sample the operation on.
    seed : int
        Seed of the dwell times, turnarounds and occupancy.
    first_departure, last_arrival : pandas.Timestamp
        Timezone-aware times of the first departure and of the end of service.
    layovers : sequence of (pandas.Timestamp, pandas.Timestamp), optional
        Layover windows (start, end), spent at a terminus (operation ``"layover"``).
    start_at_terminus : int, default 0
        0 to start at the line's first station, anything else at its last.
    preparation_min : float, default 45.0
        HVAC preparation before the first departure. [min]

    Returns
    -------
    OperationSeries
        The day's operation sampled on ``times``.

    Raises
    ------
    ValueError
        If ``times`` is not timezone-aware or uniform, or ``first_departure`` is not before
        ``last_arrival``.
    """
    _check_grid(times)
    if first_departure >= last_arrival:
        raise ValueError("first_departure must be before last_arrival")
    rng = np.random.default_rng(seed)
    st = list(line.stations) if start_at_terminus == 0 else list(line.stations)[::-1]
    lat = np.array([s.latitude_deg for s in st])
    lon = np.array([s.longitude_deg for s in st])
    hb = np.array([ZURICH_HB[1], ZURICH_HB[2]])

    # segments: (start_s, end_s, kind, data) on seconds since first_departure's epoch
    t0 = first_departure.timestamp()
    segs: list[tuple[float, float, str, dict]] = []
    t = t0
    pos = 0  # index into st of the current station; direction +1 then −1 …
    direction = 1
    pending = sorted((a.timestamp(), b.timestamp()) for a, b in layovers)
    while True:
        order = range(pos, len(st) - 1) if direction > 0 else range(pos, 0, -1)
        for i in order:
            j = i + direction
            length = float(haversine_m(lat[i], lon[i], lat[j], lon[j])) * DETOUR
            v, ta, tc, tb = run_profile(length, line.v_max_kmh)
            run_s = ta + tc + tb
            local_h = pd.Timestamp(t, unit="s", tz="UTC").tz_convert(LOCAL_TZ)
            towards = np.hypot(*(np.array([lat[j], lon[j]]) - hb)) < np.hypot(
                *(np.array([lat[i], lon[i]]) - hb)
            )
            occ = _occupancy(local_h.hour + local_h.minute / 60, bool(towards), rng)
            segs.append(
                (t, t + run_s, "run", dict(i=i, j=j, length=length, prof=(v, ta, tc, tb), occ=occ))
            )
            t += run_s
            if j in (0, len(st) - 1):
                pos = j
                break
            dwell = float(rng.uniform(30.0, 60.0))
            segs.append((t, t + dwell, "dwell", dict(i=j, occ=occ)))
            t += dwell
        direction = -direction
        if t >= last_arrival.timestamp():
            segs.append((t, np.inf, "parked", dict(i=pos)))
            break
        lay = next(((a, b) for a, b in pending if a <= t + 1800.0 and b > t), None)
        if lay is not None:
            pending.remove(lay)
            segs.append((t, lay[1], "layover", dict(i=pos)))
            t = lay[1]
        else:
            turn = float(rng.uniform(8 * 60.0, 15 * 60.0))
            segs.append((t, t + turn, "turnaround", dict(i=pos)))
            t += turn

    n = len(times)
    x = times.as_unit("ns").asi8 / 1e9
    out_lat, out_lon = np.full(n, lat[0]), np.full(n, lon[0])
    speed, occ = np.zeros(n), np.zeros(n)
    doors = np.zeros(n, dtype=bool)
    op = np.full(n, "parked", dtype=object)
    prep = x >= t0 - preparation_min * 60.0
    op[prep & (x < t0)] = "service"
    for a, b, kind, d in segs:
        i0, i1 = np.searchsorted(x, a), np.searchsorted(x, b)
        if i1 <= i0:
            continue
        sl, tau = slice(i0, i1), x[i0:i1] - a
        if kind == "run":
            i, j, (v, ta, tc, tb) = d["i"], d["j"], d["prof"]
            spd, dist = _run_state(tau, v, ta, tc, tb)
            f = dist / d["length"]
            out_lat[sl] = lat[i] + f * (lat[j] - lat[i])
            out_lon[sl] = lon[i] + f * (lon[j] - lon[i])
            speed[sl], occ[sl], op[sl] = spd * 3.6, d["occ"], "service"
            continue
        out_lat[sl], out_lon[sl] = lat[d["i"]], lon[d["i"]]
        if kind == "dwell":
            doors[sl] = (tau >= 5.0) & (tau < (b - a) - 5.0)
            occ[sl], op[sl] = d["occ"], "service"
        elif kind == "turnaround":
            doors[sl] = (tau < 120.0) | (tau >= (b - a) - 120.0)
            op[sl] = "service"
        else:
            op[sl] = kind
    return OperationSeries(
        time=times,
        latitude_deg=out_lat,
        longitude_deg=out_lon,
        heading_deg=heading_from_positions(out_lat, out_lon),
        speed_kmh=speed,
        doors_open=doors,
        occupancy_pct=occ,
        operation=op,
    )
