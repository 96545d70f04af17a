"""The environment of a simulated trial (:mod:`.trial_sim`): when its service days start, and
the weather and the train's operation over them.

**The days.** The scenario gives the place, the first date and the kind of operation. The weather
is the seeded generator's at that place over the N days (the Zurich climatology with its AR(1)
day-to-day anomaly, the scenario's mean cloud cover), so days differ as the data generator's do.
A parked scenario's train stands in regular mode all day, heading as in the scenario; an
in-service one runs each day a timetable drawn as the fleet data's
(:func:`~trainclimate.data.fleetlogs.draw_service_day`). Both coaches share weather and
operation.
"""

from __future__ import annotations

import dataclasses
import itertools
from datetime import date, timedelta

import numpy as np
import pandas as pd

from trainclimate.analysis.trial_plan import DEFAULT_SWITCH_HOUR, day_start
from trainclimate.coach.rule import MODE_REGULAR, mode_from_operation
from trainclimate.data.fleetlogs import draw_service_day, local_hours
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.routes import LINES, OperationSeries, service_day, stationary
from trainclimate.sim.seeding import seed_of
from trainclimate.sim.solar import solar_position
from trainclimate.sim.weather import SITES, generate_weather

#: Simulator step. [s]
SIM_DT_S = 10.0
#: The seed streams of a trial (the third integer of :func:`~trainclimate.sim.seeding.seed_of`):
#: its coaches' parameters, weather, operation, sensor noise and disturbance forecast.
PARAMS_STREAM, WEATHER_STREAM, OPERATION_STREAM, NOISE_STREAM, FORECAST_STREAM = range(5)


def _operation(
    scenario: scenarios.Scenario, times: pd.DatetimeIndex, starts: pd.DatetimeIndex, seed: int
) -> OperationSeries:
    """The train's operation on ``times``: parked throughout, or a drawn timetable per service
    day (``starts``: each day's start, then the end)."""
    site = SITES[scenario.site]
    if scenario.parked:
        return stationary(
            times,
            latitude_deg=site.latitude_deg,
            longitude_deg=site.longitude_deg,
            heading_deg=scenario.parked_heading_deg,
        )
    days = []
    for i, (a, b) in enumerate(itertools.pairwise(starts)):
        grid = times[(times >= a) & (times < b)]
        local_date = a.tz_convert(scenarios.LOCAL_TZ).strftime("%Y-%m-%d")
        day_seed = seed_of(scenario.seed, seed, OPERATION_STREAM, i)
        line, first, last, layovers = draw_service_day(np.random.default_rng(day_seed))
        days.append(
            service_day(
                LINES[line],
                grid,
                seed=day_seed,
                first_departure=local_hours(local_date, first),
                last_arrival=local_hours(local_date, last),
                layovers=[
                    (local_hours(local_date, s), local_hours(local_date, s + h))
                    for s, h in layovers
                ],
                start_at_terminus=day_seed % 2,
            )
        )
    columns = [f.name for f in dataclasses.fields(OperationSeries) if f.name != "time"]
    return OperationSeries(
        time=times, **{c: np.concatenate([getattr(d, c) for d in days]) for c in columns}
    )


def day_starts(
    scenario: scenarios.Scenario, days: int, switch_hour: int = DEFAULT_SWITCH_HOUR
) -> pd.DatetimeIndex:
    """When each of the trial's service days starts, from the scenario's date, and when the
    last ends: ``days + 1`` UTC times (:func:`~trainclimate.analysis.trial_plan.day_start`)."""
    first = date.fromisoformat(scenario.date)
    return pd.DatetimeIndex(
        [day_start(first + timedelta(days=i), switch_hour) for i in range(days + 1)]
    )


def trial_environment(
    scenario: scenarios.Scenario,
    days: int,
    seed: int,
    switch_hour: int = DEFAULT_SWITCH_HOUR,
) -> Environment:
    """The train's N service days from the scenario's date (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        Gives the site, the first date, the mean cloud cover and parked or in service.
    days : int
        Service days N.
    seed : int
        The trial's seed (weather and operation).
    switch_hour : int, default 3
        Local hour a service day starts. [h]

    Returns
    -------
    Environment
        One coach column on a 10-s grid from the first day's switch hour to the N-th's end.
    """
    starts = day_starts(scenario, days, switch_hour)
    step = pd.Timedelta(seconds=SIM_DT_S)
    times = pd.date_range(starts[0], starts[-1], freq=step, inclusive="left")
    site = SITES[scenario.site]
    weather = generate_weather(
        site,
        starts[0] - pd.Timedelta(hours=1),
        starts[-1] + pd.Timedelta(hours=1),
        seed=seed_of(scenario.seed, seed, WEATHER_STREAM),
        cloud_cover=scenario.cloud_cover,
    )
    t_amb, ghi = weather.at(times)
    sun = solar_position(times, site.latitude_deg, site.longitude_deg, site.altitude_m)
    op = _operation(scenario, times, starts, seed)
    if scenario.parked:
        mode = np.full(len(times), MODE_REGULAR, dtype=np.int8)
    else:
        mode = mode_from_operation(op.operation)
    return Environment.of_operations(times, t_amb, ghi, sun, [op], mode[:, None])
