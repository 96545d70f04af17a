"""What a fleet study simulates: the study's inputs, its chunks and each coach-day's operation.

A study is a fleet of coaches (each with its own parameters) over a run of days. Every coach-day
is drawn from the study's seed, the coach and the day, and nothing else: whether the coach stands
parked all day with its HVAC in regular mode (as in the paper's experiments, Section V) or runs
a Zurich S-Bahn service day (first departure, end of service, layovers; in the depot with the
HVAC off outside it), and the day's occupancy scaled by the study's factor. A day runs from
03:00 to 03:00 local time (23–25 h around the changes of daylight saving time), from the
simulator's initial state, so coach-days are independent and any set of them can be simulated
anywhere. The work is cut into chunks of ``chunk_coaches`` coaches × ``chunk_days`` days, each
a pure function of the study and its coordinates.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import pandas as pd

from trainclimate.coach.rule import MODE_REGULAR, mode_from_operation
from trainclimate.control.forecast import FORECASTS
from trainclimate.control.ocp import DEFAULT_OBJECTIVE, OBJECTIVES
from trainclimate.data.fleetlogs import draw_service_day, local_hours
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, diversify
from trainclimate.sim.routes import LINES, service_day, stationary
from trainclimate.sim.seeding import seed_of
from trainclimate.sim.solar import solar_position
from trainclimate.sim.weather import SITES, Weather, generate_weather

#: The controllers a study can compare; ``rule`` is the baseline and always runs.
STUDY_CONTROLLERS = ("rule", "ddpc", "edge")
#: The simulator's step. [s]
SIM_DT_S = 10.0
#: Where the fleet runs and stands (the weather generator's site and the solar geometry).
SITE = "zurich"


class StudyError(ValueError):
    """A study that cannot be run as asked (the message says why)."""


@dataclass(frozen=True)
class Chunk:
    """Coaches ``coach_lo`` … ``coach_hi − 1`` over days ``day_lo`` … ``day_hi − 1`` (indices)."""

    coach_lo: int
    coach_hi: int
    day_lo: int
    day_hi: int

    @property
    def key(self) -> str:
        """The chunk's file stem, e.g. ``c00000-00031_d000-006``."""
        return (
            f"c{self.coach_lo:05d}-{self.coach_hi - 1:05d}_d{self.day_lo:03d}-{self.day_hi - 1:03d}"
        )

    @property
    def coach_days(self) -> int:
        """Number of coach-days in the chunk."""
        return (self.coach_hi - self.coach_lo) * (self.day_hi - self.day_lo)


@dataclass(frozen=True)
class StudySpec:
    """Everything a study's numbers depend on.

    Attributes
    ----------
    coach_ids : tuple of str
        The fleet's coaches.
    coach_params : tuple of dict
        Each coach's parameters (:meth:`CoachParams.to_dict`), before the spread.
    start : str
        First local day, ``YYYY-MM-DD``.
    days : int
        Number of days.
    controllers : tuple of str
        ``rule`` first, then ``ddpc`` and optionally ``edge``.
    parked_share : float
        Share of coach-days parked all day with the HVAC in regular mode. [–]
    occupancy_scale : float
        Factor on the service's seeded occupancy. [–]
    coach_spread : float
        Each coach's parameters drawn ±this around its own (0: as given). [–]
    seed : int
        Seed of the operation, the spread, the sensor noise and the generated weather.
    weather_source : str
        ``"generated"`` or the weather file's name and hash (identifies the weather).
    chunk_coaches, chunk_days : int
        The chunk size.
    forecast : str
        The DDPC layer's disturbance forecast, one of
        :data:`~trainclimate.control.forecast.FORECASTS`: ``persistence`` (the default, the
        current disturbance held over the horizon, what the service's controller gets),
        ``perfect`` (the true future, the paper's simulation study) or ``noisy``. The band-edge
        reference always gets the perfect one.
    objective : str
        The DDPC layer's objective, one of :data:`~trainclimate.control.ocp.OBJECTIVES`.
    model : str
        The prediction model's identity (its name and hash).
    """

    coach_ids: tuple[str, ...]
    coach_params: tuple[dict, ...] = field(repr=False)
    start: str
    days: int
    controllers: tuple[str, ...] = ("rule", "ddpc")
    parked_share: float = 0.15
    occupancy_scale: float = 1.0
    coach_spread: float = 0.15
    seed: int = 2025
    weather_source: str = "generated"
    chunk_coaches: int = 64
    chunk_days: int = 7
    forecast: str = "persistence"
    objective: str = DEFAULT_OBJECTIVE
    model: str = ""

    def __post_init__(self) -> None:
        if not self.coach_ids:
            raise StudyError("the study needs at least one coach")
        if len(self.coach_params) != len(self.coach_ids):
            raise StudyError("one parameter set per coach")
        if len(set(self.coach_ids)) != len(self.coach_ids):
            raise StudyError("coach ids must be unique")
        if self.days < 1:
            raise StudyError("--days must be at least 1")
        try:
            pd.Timestamp(self.start)
        except ValueError as exc:
            raise StudyError(f"--start {self.start!r} is not a date (YYYY-MM-DD)") from exc
        ctl = self.controllers
        unknown = [c for c in ctl if c not in STUDY_CONTROLLERS]
        if unknown or ctl[:1] != ("rule",) or "ddpc" not in ctl or len(set(ctl)) != len(ctl):
            raise StudyError(
                "--controllers: rule,ddpc or rule,ddpc,edge (rule is the baseline, ddpc the layer)"
            )
        if not 0.0 <= self.parked_share <= 1.0:
            raise StudyError("--parked-share must lie in [0, 1]")
        if not 0.0 <= self.occupancy_scale <= 3.0:
            raise StudyError("--occupancy-scale must lie in [0, 3]")
        if not 0.0 <= self.coach_spread < 1.0:
            raise StudyError("--coach-spread must lie in [0, 1)")
        if self.forecast not in FORECASTS:
            raise StudyError(f"--forecast: one of {', '.join(FORECASTS)}")
        if self.objective not in OBJECTIVES:
            raise StudyError(f"--objective: one of {', '.join(OBJECTIVES)}")
        if self.chunk_coaches < 1 or self.chunk_days < 1:
            raise StudyError("--chunk-coaches and --chunk-days must be at least 1")

    @property
    def n_coaches(self) -> int:
        """Number of coaches."""
        return len(self.coach_ids)

    @property
    def dates(self) -> list[str]:
        """The study's local days, ``YYYY-MM-DD``."""
        return [d.strftime("%Y-%m-%d") for d in pd.date_range(self.start, periods=self.days)]

    @property
    def coach_days(self) -> int:
        """Coaches × days."""
        return self.n_coaches * self.days

    def chunks(self) -> list[Chunk]:
        """The study cut into chunks, coaches fastest."""
        return [
            Chunk(
                c,
                min(c + self.chunk_coaches, self.n_coaches),
                d,
                min(d + self.chunk_days, self.days),
            )
            for d in range(0, self.days, self.chunk_days)
            for c in range(0, self.n_coaches, self.chunk_coaches)
        ]

    def fingerprint(self) -> str:
        """A hash of everything the numbers depend on (a ``--out`` holds one study)."""
        blob = json.dumps(asdict(self), sort_keys=True, default=str).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def params_of(self, coach: int) -> CoachParams:
        """Coach ``coach``'s parameters: its own, spread by :attr:`coach_spread` from its seed."""
        base = CoachParams.from_dict(self.coach_params[coach])
        if self.coach_spread == 0:
            return base
        return diversify(base, 1, seed=seed_of(self.seed, 1, coach), spread=self.coach_spread)[0]

    def first_utc(self) -> pd.Timestamp:
        """03:00 local on the first day, in UTC."""
        return local_hours(self.start, 3.0)

    def end_utc(self) -> pd.Timestamp:
        """03:00 local after the last day, in UTC."""
        return local_hours(self.dates[-1], 27.0)


def study_weather(spec: StudySpec) -> Weather:
    """The seeded generator's weather at the study's site, an hour either side of its days
    (Zurich climatology with day-to-day anomalies and clouds,
    :func:`~trainclimate.sim.weather.generate_weather`)."""
    return generate_weather(
        SITES[SITE],
        spec.first_utc() - pd.Timedelta(hours=1),
        spec.end_utc() + pd.Timedelta(hours=1),
        seed=spec.seed,
    )


def check_weather(weather: Weather, spec: StudySpec) -> None:
    """Raise :class:`StudyError` unless ``weather`` covers every simulated minute of the study."""
    first, end = spec.first_utc(), spec.end_utc()
    if weather.time[0] > first or weather.time[-1] < end - pd.Timedelta(seconds=SIM_DT_S):
        raise StudyError(
            f"--weather covers {weather.time[0]:%Y-%m-%d %H:%M} … {weather.time[-1]:%Y-%m-%d %H:%M}"
            f" UTC; the study needs {first:%Y-%m-%d %H:%M} … {end:%Y-%m-%d %H:%M} UTC"
        )


@dataclass(frozen=True)
class CoachDay:
    """One coach-day's operation (drawn by :func:`plan_coach_day`)."""

    parked: bool
    line: str = ""
    first_departure: pd.Timestamp | None = None
    last_arrival: pd.Timestamp | None = None
    layovers: tuple = ()
    seed: int = 0


def plan_coach_day(spec: StudySpec, coach: int, day: int) -> CoachDay:
    """Coach ``coach``'s operation on day ``day`` (indices), from the study's seed alone."""
    seed = seed_of(spec.seed, 2, coach, day)
    rng = np.random.default_rng(seed)
    if rng.random() < spec.parked_share:
        return CoachDay(parked=True, seed=seed)
    date = spec.dates[day]
    line, first, last, layovers = draw_service_day(rng)
    return CoachDay(
        parked=False,
        line=line,
        first_departure=local_hours(date, first),
        last_arrival=local_hours(date, last),
        layovers=tuple((local_hours(date, a), local_hours(date, a + b)) for a, b in layovers),
        seed=seed,
    )


def day_grid(date: str) -> pd.DatetimeIndex:
    """The simulator's grid over a study day: 03:00 local to 03:00 local the next day, in UTC."""
    start = local_hours(date, 3.0)
    end = local_hours(date, 27.0)
    return pd.date_range(start, end, freq=pd.Timedelta(seconds=SIM_DT_S), inclusive="left")


def day_environment(
    spec: StudySpec, weather: Weather, coaches: range, day: int
) -> tuple[Environment, list[CoachDay]]:
    """The environment of ``coaches`` on study day ``day`` and their plans.

    A parked coach stands outdoors at the site, heading east, with the HVAC in regular mode all
    day; a coach in service runs its plan (:func:`~trainclimate.sim.routes.service_day`), its
    occupancy scaled by :attr:`StudySpec.occupancy_scale` (within 0–150 % of seats).
    """
    site = SITES[SITE]
    times = day_grid(spec.dates[day])
    t_amb, ghi = weather.at(times)
    sun = solar_position(times, site.latitude_deg, site.longitude_deg, site.altitude_m)
    plans = [plan_coach_day(spec, c, day) for c in coaches]
    ops, modes = [], []
    for plan in plans:
        if plan.parked:
            op = stationary(
                times,
                latitude_deg=site.latitude_deg,
                longitude_deg=site.longitude_deg,
                heading_deg=90.0,
            )
            modes.append(np.full(len(times), MODE_REGULAR, dtype=np.int8))
        else:
            op = service_day(
                LINES[plan.line],
                times,
                seed=plan.seed,
                first_departure=plan.first_departure,
                last_arrival=plan.last_arrival,
                layovers=list(plan.layovers),
                start_at_terminus=plan.seed % 2,
            )
            modes.append(mode_from_operation(op.operation))
        scaled = np.clip(op.occupancy_pct * spec.occupancy_scale, 0.0, 150.0)
        ops.append(replace(op, occupancy_pct=scaled))

    return Environment.of_operations(times, t_amb, ghi, sun, ops, np.column_stack(modes)), plans
