"""Named, seeded scenarios: where and when a fleet of half coaches runs, and how.

A scenario fixes the place (weather and solar geometry), the day and its weather character
(daily minimum/maximum and cloudiness, fed to the seeded weather generator), and the operation:
an in-service day on Zurich S-Bahn lines, or — like the paper's experiments (Section V) — an
empty train parked outdoors with its HVAC in regular mode throughout. The same name and seed
always give the same environment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from trainclimate.coach.rule import MODE_REGULAR, mode_from_operation
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, diversify
from trainclimate.sim.routes import LINES, service_day, stationary
from trainclimate.sim.solar import solar_position
from trainclimate.sim.weather import SITES, Weather, generate_weather

LOCAL_TZ = "Europe/Zurich"


class ScenarioError(ValueError):
    """An unknown scenario or an impossible request for one."""


@dataclass(frozen=True)
class Service:
    """An in-service day: coach i runs ``lines[i % len(lines)]`` back and forth.

    Clock times are local (Europe/Zurich) ``"HH:MM"`` on the scenario's first day, with ``+1``
    for the next day (``"01:00+1"``).

    Attributes
    ----------
    lines : tuple of str
        Names of lines in :data:`~trainclimate.sim.routes.LINES`.
    first_departure, last_arrival : str
        Local clock times of the first departure and of the end of service.
    layovers : tuple of (str, str)
        Local clock (start, end) of each layover.
    """

    lines: tuple[str, ...]
    first_departure: str
    last_arrival: str
    layovers: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class Scenario:
    """A reproducible simulation setting (see the module docstring).

    Attributes
    ----------
    name, description : str
        Key in :data:`SCENARIOS` and a one-line description.
    site : str
        Key in :data:`~trainclimate.sim.weather.SITES`.
    date : str
        Local date of the start, ``YYYY-MM-DD``.
    start : str
        Local clock time of the start, ``HH:MM``.
    hours : float
        Duration. [h]
    t_min_c, t_max_c : float
        Daily minimum and maximum ambient temperature for the weather generator. [°C]
    cloud_cover : float
        Mean cloud cover in [0, 1]. [–]
    seed : int
        Seed of the weather, the operation and the coach diversity.
    service : Service or None
        The in-service day, or None for an empty train parked outdoors.
    parked_heading_deg : float
        Heading of the parked train, clockwise from north. [°]
    notes : tuple of str
        Free-form notes.
    """

    name: str
    description: str
    site: str
    date: str  # local date of the start, YYYY-MM-DD
    start: str  # local clock time of the start, HH:MM
    hours: float
    t_min_c: float
    t_max_c: float
    cloud_cover: float
    seed: int
    service: Service | None = None
    parked_heading_deg: float = 90.0
    notes: tuple[str, ...] = field(default=())

    @property
    def parked(self) -> bool:
        """An empty train standing outdoors with the HVAC in regular mode (paper, Section V)."""
        return self.service is None

    def start_utc(self) -> pd.Timestamp:
        """The start of the scenario.

        Returns
        -------
        pandas.Timestamp
            ``date`` and ``start`` (Europe/Zurich local time), converted to UTC.
        """
        return pd.Timestamp(f"{self.date} {self.start}", tz=LOCAL_TZ).tz_convert("UTC")


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            name="winter-day",
            description="Zurich in-service day like March 28-29, 2022 (paper, Section IV.B): "
            "cold sunny spring day, service 04:15-01:00 on S-Bahn lines, one layover",
            site="zurich",
            date="2022-03-28",
            start="03:00",
            hours=23.0,
            t_min_c=1.0,
            t_max_c=15.0,
            cloud_cover=0.2,
            seed=20220328,
            service=Service(
                lines=("S12", "S8", "S14"),
                first_departure="04:15",
                last_arrival="01:00+1",
                layovers=(("10:10", "11:00"),),
            ),
        ),
        Scenario(
            name="parked-cooling-oct",
            description="Empty train parked outdoors in Muelligen, Oct 9, 2024 (paper, Exp. 1): "
            "moderate weather with sun, HVAC in regular mode",
            site="muelligen",
            date="2024-10-09",
            start="11:00",
            hours=9.0,
            t_min_c=9.0,
            t_max_c=19.0,
            cloud_cover=0.3,
            seed=20241009,
            parked_heading_deg=75.0,
        ),
        Scenario(
            name="parked-cooling-aug-conservative",
            description="Empty train parked outdoors in Wiesendangen, Aug 15, 2024 "
            "(paper, Exp. 2): hot and sunny, a tighter comfort bound inside the controller",
            site="wiesendangen",
            date="2024-08-15",
            start="09:00",
            hours=10.0,
            t_min_c=18.0,
            t_max_c=32.0,
            cloud_cover=0.15,
            seed=20240815,
            parked_heading_deg=120.0,
        ),
        Scenario(
            name="parked-cooling-aug-energy",
            description="Empty train parked outdoors in Muelligen, Aug 22, 2024 (paper, Exp. 3): "
            "hot and sunny, weights favouring energy",
            site="muelligen",
            date="2024-08-22",
            start="09:00",
            hours=10.0,
            t_min_c=17.0,
            t_max_c=31.0,
            cloud_cover=0.2,
            seed=20240822,
            parked_heading_deg=75.0,
        ),
        Scenario(
            name="parked-heating-nov",
            description="Empty train parked outdoors in Zug, Nov 28, 2024 (paper, Exp. 4): "
            "cold and overcast, HVAC in regular mode",
            site="zug",
            date="2024-11-28",
            start="07:00",
            hours=10.0,
            t_min_c=-1.0,
            t_max_c=4.0,
            cloud_cover=0.8,
            seed=20241128,
            parked_heading_deg=160.0,
        ),
    )
}


def get(name: str) -> Scenario:
    """Look up a scenario by name.

    Parameters
    ----------
    name : str
        A key of :data:`SCENARIOS`.

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        For an unknown name, listing the known ones.
    """
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ScenarioError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})") from None


def local_clock(day: pd.Timestamp, clock: str) -> pd.Timestamp:
    """Convert a local clock time on a given day to a UTC timestamp.

    Parameters
    ----------
    day : pandas.Timestamp
        Timezone-aware; its Europe/Zurich calendar day is used.
    clock : str
        ``"HH:MM"``, or ``"HH:MM+1"`` for the next day.

    Returns
    -------
    pandas.Timestamp
        UTC.
    """
    hhmm, _, plus = clock.partition("+")
    local_day = day.tz_convert(LOCAL_TZ).normalize().tz_localize(None)
    stamp = local_day + pd.Timedelta(days=int(plus or 0)) + pd.Timedelta(f"{hhmm}:00")
    return stamp.tz_localize(LOCAL_TZ).tz_convert("UTC")


def time_grid(start: pd.Timestamp, hours: float, dt_s: float) -> pd.DatetimeIndex:
    """Uniform UTC time grid.

    Parameters
    ----------
    start : pandas.Timestamp
        Timezone-aware first time.
    hours : float
        Length of the grid, end excluded. [h]
    dt_s : float
        Step. [s]

    Returns
    -------
    pandas.DatetimeIndex
        ``round(hours · 3600 / dt_s)`` UTC times.

    Raises
    ------
    ScenarioError
        If ``hours`` is not positive or shorter than two steps.
    """
    if hours <= 0:
        raise ScenarioError(f"hours must be positive, got {hours:g}")
    n = round(hours * 3600.0 / dt_s)
    if n < 2:
        raise ScenarioError(f"hours = {hours:g} is shorter than two simulator steps of {dt_s:g} s")
    return pd.date_range(start.tz_convert("UTC"), periods=n, freq=pd.Timedelta(seconds=dt_s))


def coach_params(base: CoachParams, n: int, seed: int) -> list[CoachParams]:
    """Parameter sets of a scenario's coaches.

    Parameters
    ----------
    base : CoachParams
        Coach 0's parameters.
    n : int
        Number of coaches.
    seed : int
        Seed of the variations.

    Returns
    -------
    list of CoachParams
        ``base`` itself, then n − 1 seeded variations of it (±15 %,
        :func:`~trainclimate.sim.params.diversify`).
    """
    return [base, *diversify(base, n - 1, seed=seed)] if n > 1 else [base]


def build(
    scenario: Scenario,
    *,
    n_coaches: int = 1,
    dt_s: float = 10.0,
    hours: float | None = None,
    weather: Weather | None = None,
    base_params: CoachParams | None = None,
) -> tuple[Environment, list[CoachParams]]:
    """Build the environment and per-coach parameters of a scenario.

    With ``weather`` (e.g. a measured CSV) the run starts at its first time and lasts ``hours``
    (default: its span); the scenario still gives place, operation and occupancy, shifted to the
    weather's local date. Solar geometry is computed from time and the scenario's site (the
    ≤ 50 km a train covers on its line shifts the sun by < 0.5°). Coaches of a parked scenario
    are in regular mode throughout; in service the mode follows the operation.

    Parameters
    ----------
    scenario : Scenario
        The setting.
    n_coaches : int, default 1
        Number of coaches N; in service coach i runs the scenario's line i modulo their number.
    dt_s : float, default 10.0
        Simulator step. [s]
    hours : float, optional
        Duration (default: the scenario's, or the weather's span). [h]
    weather : Weather, optional
        Measured weather to use instead of the generator.
    base_params : CoachParams, optional
        Coach 0's parameters (default: :class:`CoachParams`).

    Returns
    -------
    env : Environment
        The disturbances and operation of the N coaches.
    params : list of CoachParams
        One parameter set per coach (:func:`coach_params`).

    Raises
    ------
    ScenarioError
        If ``n_coaches`` < 1, or ``hours`` is invalid or exceeds the weather's span.
    """
    if n_coaches < 1:
        raise ScenarioError(f"need at least one coach, got {n_coaches}")
    site = SITES[scenario.site]
    if weather is not None:
        start = weather.time[0]
        hours = weather.span_hours if hours is None else hours
        if hours > weather.span_hours + 1e-9:
            raise ScenarioError(
                f"--hours {hours:g} exceeds the weather file's span of {weather.span_hours:g} h"
            )
    else:
        start = scenario.start_utc()
        hours = scenario.hours if hours is None else hours
    times = time_grid(start, hours, dt_s)
    if weather is None:
        weather = generate_weather(
            site,
            times[0] - pd.Timedelta(hours=1),
            times[-1] + pd.Timedelta(hours=1),
            seed=scenario.seed,
            t_min_c=scenario.t_min_c,
            t_max_c=scenario.t_max_c,
            cloud_cover=scenario.cloud_cover,
        )
    t_amb, ghi = weather.at(times)
    sun = solar_position(times, site.latitude_deg, site.longitude_deg, site.altitude_m)

    ops = []
    for i in range(n_coaches):
        if scenario.service is None:
            ops.append(
                stationary(
                    times,
                    latitude_deg=site.latitude_deg,
                    longitude_deg=site.longitude_deg,
                    heading_deg=scenario.parked_heading_deg,
                )
            )
            continue
        svc = scenario.service
        ops.append(
            service_day(
                LINES[svc.lines[i % len(svc.lines)]],
                times,
                seed=scenario.seed + i,
                first_departure=local_clock(times[0], svc.first_departure),
                last_arrival=local_clock(times[0], svc.last_arrival),
                layovers=[
                    (local_clock(times[0], a), local_clock(times[0], b)) for a, b in svc.layovers
                ],
                start_at_terminus=0 if i % 2 == 0 else -1,
            )
        )
    if scenario.parked:
        mode = np.full((len(times), n_coaches), MODE_REGULAR, dtype=np.int8)
    else:
        mode = np.column_stack([mode_from_operation(o.operation) for o in ops])
    env = Environment.of_operations(times, t_amb, ghi, sun, ops, mode)
    params = coach_params(base_params or CoachParams(), n_coaches, scenario.seed)
    return env, params
