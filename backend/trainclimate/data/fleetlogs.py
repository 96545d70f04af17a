"""Seeded raw fleet logs from the simulator, like SBB's two measurement campaigns (Section III.A).

- Winter/Spring: 8 coaches in 8 trains, 2022-02-22 … 2022-03-31; HVAC every 1 min, weather every
  10 min, train recordings per trip.
- Summer: 4 coaches of 4 of those trains, 2023-07-04 … 2023-07-23; HVAC every 2 s, weather every
  1 min.

Each coach has its own parameters (:func:`trainclimate.sim.params.diversify`). Each coach-day is
planned from its own seed: whether the logger ran, whether the train was in service (else it
stands in the depot with the HVAC off), the line it ran (Zurich S-Bahn), its first departure, last
arrival and layovers (slumber mode), and the driver's setpoint changes (±0.5…2 K for 20 min to
3 h, the intervention the paper describes; they are also what makes T_ref informative in
winter, when the rule curve is flat). The day runs from 03:00 to 03:00 local time.

The simulator steps at 10 s. The HVAC log samples the true room temperatures (linear between
steps: < 0.01 K error, far below the sensors' 0.1 K) through each coach's sensor model — noise
and 0.1 K quantisation — at the campaign's rate; T_ref, mode and speed are read at the same
times, and the electrical power meter gives the climate system's mean power over each sample's
interval [t, t + period), at the meter's :data:`POWER_QUANTUM_KW` resolution. The weather log
gives the train's position, the regional weather (plus a small local anomaly per train) and the
solar elevation and azimuth at the train's position (pvlib). The trips log has one row per trip
with its mean occupancy.

Then the defects of real exports are added (:class:`Defects`): communication gaps from a minute
to hours, duplicated and out-of-order rows, sensor spikes, empty fields, garbage lines and the
occasional unreadable file, each drawn from the coach-day's seed; and the power meter's own
dropouts (the power field empty for a minute to two hours), drawn from a stream of their own so
that the other defects are those of logs without a meter. Coach-days are simulated in
batches (as columns of one vectorised fleet), so memory is bounded by the batch, not the campaign.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from trainclimate.coach.rule import MODE_NAMES, RuleCurve, mode_from_operation
from trainclimate.data.defects import Defects, add_defects, power_dropouts
from trainclimate.data.formats import (
    CANONICAL,
    SUMMER_FORMAT,
    WINTER_FORMAT,
    ExportFormat,
    log_path,
    to_export,
    write_export,
)
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams, diversify
from trainclimate.sim.routes import LINES, haversine_m, service_day, stationary
from trainclimate.sim.simulator import FleetSimulator
from trainclimate.sim.solar import solar_position
from trainclimate.sim.weather import SITES, Weather, generate_weather

LOCAL_TZ = "Europe/Zurich"
SIM_DT_S = 10.0
#: Every coach-day is simulated over this many hours (a local day is 23–25 h around DST).
DAY_HOURS_MAX = 25.0
#: Resolution of the HVAC power meter's readings. [kW]
POWER_QUANTUM_KW = 0.01


@dataclass(frozen=True)
class Campaign:
    """One measurement campaign: its days (local dates, inclusive), trains and coaches, logging
    periods (s) and export format."""

    name: str
    first_day: str
    last_day: str
    trains: tuple[str, ...]
    coaches: tuple[str, ...]
    hvac_period_s: float
    weather_period_s: float
    fmt: ExportFormat
    seed: int
    #: index of each coach's parameter set in the fleet (so campaigns share no coach)
    param_offset: int = 0

    @property
    def days(self) -> list[str]:
        """The campaign's days, local dates ``YYYY-MM-DD``, first to last."""
        return [d.strftime("%Y-%m-%d") for d in pd.date_range(self.first_day, self.last_day)]


_TRAINS = ("124", "44", "66", "17", "31", "58", "93", "105")
WINTER_SPRING = Campaign(
    name="winter-spring",
    first_day="2022-02-22",
    last_day="2022-03-31",
    trains=_TRAINS,
    coaches=tuple(f"{t}A" for t in _TRAINS),
    hvac_period_s=60.0,
    weather_period_s=600.0,
    fmt=WINTER_FORMAT,
    seed=2022,
)
SUMMER = Campaign(
    name="summer",
    first_day="2023-07-04",
    last_day="2023-07-23",
    trains=_TRAINS[:4],
    coaches=tuple(f"{t}B" for t in _TRAINS[:4]),
    hvac_period_s=2.0,
    weather_period_s=60.0,
    fmt=SUMMER_FORMAT,
    seed=2023,
    param_offset=len(_TRAINS),
)
CAMPAIGNS = {c.name: c for c in (WINTER_SPRING, SUMMER)}
#: Seed of the fleet's coach parameters (12 coaches: the campaigns' coaches in order).
FLEET_PARAMS_SEED = 511


def fleet_params(n: int = 12) -> list[CoachParams]:
    """The parameters of the fleet's logged coaches (seeded ±15 % around the default)."""
    return diversify(CoachParams(), n, seed=FLEET_PARAMS_SEED)


# --- planning a coach-day --------------------------------------------------------------------
@dataclass(frozen=True)
class CoachDay:
    """What happened to one coach on one day (drawn from the coach-day's seed)."""

    campaign: Campaign
    coach_index: int
    day: str
    logged: bool
    in_service: bool
    line: str
    first_departure: pd.Timestamp
    last_arrival: pd.Timestamp
    layovers: tuple[tuple[pd.Timestamp, pd.Timestamp], ...]
    #: driver setpoint changes: (start, end, offset K)
    interventions: tuple[tuple[pd.Timestamp, pd.Timestamp, float], ...]
    seed: int

    @property
    def coach(self) -> str:
        """The coach's id (e.g. ``44A``)."""
        return self.campaign.coaches[self.coach_index]

    @property
    def train(self) -> str:
        """The train's id (e.g. ``44``)."""
        return self.campaign.trains[self.coach_index]

    @property
    def start(self) -> pd.Timestamp:
        """03:00 local on the day, in UTC."""
        return pd.Timestamp(f"{self.day} 03:00", tz=LOCAL_TZ).tz_convert("UTC")

    @property
    def end(self) -> pd.Timestamp:
        """03:00 local on the next day, in UTC."""
        nxt = pd.Timestamp(self.day) + pd.Timedelta(days=1)
        return pd.Timestamp(f"{nxt:%Y-%m-%d} 03:00", tz=LOCAL_TZ).tz_convert("UTC")


def local_hours(day: str, hours: float) -> pd.Timestamp:
    """Local clock time ``hours`` after midnight of ``day`` (may pass midnight), in UTC."""
    minutes = round(hours * 60)
    stamp = pd.Timestamp(day) + pd.Timedelta(minutes=minutes)
    return stamp.tz_localize(LOCAL_TZ, nonexistent="shift_forward", ambiguous=True).tz_convert(
        "UTC"
    )


def draw_service_day(rng: np.random.Generator) -> tuple[str, float, float, list]:
    """An in-service day's timetable drawn from ``rng``: a Zurich S-Bahn line, the first
    departure (04:45–06:45), the end of service (22:00–00:45) and one or two layovers (late
    morning 40 min–2 h; in half the days also early evening 30 min–1.5 h).

    Returns
    -------
    line : str
        A key of :data:`~trainclimate.sim.routes.LINES`.
    first, last : float
        Hours after local midnight of the first departure and of the end of service. [h]
    layovers : list of (float, float)
        (start in hours after local midnight, length in hours) of each layover. [h]
    """
    line = str(rng.choice(sorted(LINES)))
    first = rng.uniform(4.75, 6.75)
    last = rng.uniform(22.0, 24.75)
    layovers = [(rng.uniform(9.5, 13.5), rng.uniform(0.67, 2.0))]
    if rng.random() < 0.5:
        layovers.append((rng.uniform(18.5, 20.5), rng.uniform(0.5, 1.5)))
    return line, first, last, layovers


def plan_day(campaign: Campaign, coach_index: int, day_index: int, rates: Defects) -> CoachDay:
    """Draw one coach-day's operation from its seed (see the module docstring)."""
    seed = int(np.random.SeedSequence([campaign.seed, coach_index, day_index]).generate_state(1)[0])
    rng = np.random.default_rng(seed)
    day = campaign.days[day_index]
    logged = bool(rng.random() >= rates.logger_off_day)
    in_service = bool(rng.random() < 0.85)
    line, first, last, layovers = draw_service_day(rng)
    interventions = []
    for _ in range(rng.poisson(3.0)):
        a = rng.uniform(first, last)
        length = rng.uniform(1 / 3, 3.0)
        offset = float(rng.choice([-2.0, -1.5, -1.0, -0.5, 0.5, 1.0, 1.5, 2.0]))
        interventions.append((local_hours(day, a), local_hours(day, a + length), offset))
    return CoachDay(
        campaign=campaign,
        coach_index=coach_index,
        day=day,
        logged=logged,
        in_service=in_service,
        line=line,
        first_departure=local_hours(day, first),
        last_arrival=local_hours(day, last),
        layovers=tuple((local_hours(day, a), local_hours(day, a + b)) for a, b in layovers),
        interventions=tuple(sorted(interventions)),
        seed=seed,
    )


def driver_offset(plan: CoachDay, times: pd.DatetimeIndex) -> np.ndarray:
    """The driver's setpoint offset (K) at ``times``; a later change replaces an earlier one."""
    out = np.zeros(len(times))
    for a, b, offset in plan.interventions:
        out[(times >= a) & (times < b)] = offset
    return out


# --- weather ---------------------------------------------------------------------------------
def campaign_weather(campaign: Campaign) -> dict[str, Weather]:
    """Regional weather over the campaign (Zurich climatology, seeded), plus each train's own
    local anomaly (AR(1), σ 0.5 K, 3 h persistence): trains on different lines see different
    temperatures."""
    site = SITES["zurich"]
    start = pd.Timestamp(campaign.first_day, tz=LOCAL_TZ) - pd.Timedelta(days=1)
    end = pd.Timestamp(campaign.last_day, tz=LOCAL_TZ) + pd.Timedelta(days=2)
    regional = generate_weather(site, start, end, seed=campaign.seed, step_s=600.0)
    phi = np.exp(-600.0 / (3 * 3600.0))
    out = {}
    for i, train in enumerate(campaign.trains):
        rng = np.random.default_rng([campaign.seed, 9999, i])
        z = np.empty(len(regional.time))
        z[0] = rng.normal(0, 0.5)
        for k in range(1, len(z)):
            z[k] = phi * z[k - 1] + np.sqrt(1 - phi**2) * rng.normal(0, 0.5)
        out[train] = Weather(regional.time, regional.t_amb_c + z, regional.ghi_w_m2)
    return out


# --- simulate a batch of coach-days ----------------------------------------------------------
def _environment(plan: CoachDay, weather: Weather, sun: pd.DataFrame, times):
    """The simulator's environment for one coach-day, and the train's operation series."""
    site = SITES["zurich"]
    if plan.in_service:
        line = LINES[plan.line]
        ops = service_day(
            line,
            times,
            seed=plan.seed,
            first_departure=plan.first_departure,
            last_arrival=plan.last_arrival,
            layovers=list(plan.layovers),
            start_at_terminus=plan.seed % 2,
        )
    else:
        ops = stationary(
            times,
            latitude_deg=site.latitude_deg + 0.04,
            longitude_deg=site.longitude_deg - 0.08,
            heading_deg=90.0,
            operation="parked",
        )
    t_amb, ghi = weather.at(times)
    env = Environment(
        time=times,
        t_amb_c=t_amb,
        ghi_w_m2=ghi,
        zenith_deg=sun["zenith_deg"].to_numpy(),
        azimuth_deg=sun["azimuth_deg"].to_numpy(),
        heading_deg=ops.heading_deg,
        speed_kmh=ops.speed_kmh,
        occupancy_pct=ops.occupancy_pct,
        door_open=ops.doors_open.astype(float),
        mode=mode_from_operation(ops.operation),
    )
    return env, ops


def _trips(ops, n: int, train: str, line: str) -> pd.DataFrame:
    """One row per trip (a maximal stretch with passengers aboard) in the first ``n`` steps of
    ``ops``: times, termini, mean load."""
    times, occ = ops.time[:n], ops.occupancy_pct[:n]
    on = np.concatenate([[False], occ > 0, [False]])
    starts = np.flatnonzero(on[1:] & ~on[:-1])
    ends = np.flatnonzero(~on[1:] & on[:-1])
    stations = LINES[line].stations if line in LINES else ()
    lat = np.array([s.latitude_deg for s in stations])
    lon = np.array([s.longitude_deg for s in stations])

    def nearest(i: int) -> str:
        if not len(stations):
            return ""
        dist = haversine_m(ops.latitude_deg[i], ops.longitude_deg[i], lat, lon)
        return stations[int(np.argmin(dist))].name

    dt = times[1] - times[0]
    rows = [
        dict(
            train=train,
            departure=times[a],
            arrival=times[b - 1] + dt,
            origin=nearest(a),
            destination=nearest(b - 1),
            occupancy_pct=float(occ[a:b].mean()),
        )
        for a, b in zip(starts, ends, strict=True)
    ]
    frame = pd.DataFrame(rows, columns=list(CANONICAL["trips"]))
    for col in ("departure", "arrival"):
        frame[col] = pd.to_datetime(frame[col], utc=True)
    return frame


def _sample_times(start: pd.Timestamp, end: pd.Timestamp, period_s: float) -> pd.DatetimeIndex:
    return pd.date_range(start, end, freq=pd.Timedelta(seconds=period_s), inclusive="left")


def _seconds(times: pd.DatetimeIndex) -> np.ndarray:
    """Seconds since the epoch (float), whatever the index's resolution."""
    return times.as_unit("ns").asi8 / 1e9


def _interp(times_s: np.ndarray, grid_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.interp(times_s, grid_s, values)


def _hold(times_s: np.ndarray, grid_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    idx = np.clip(np.searchsorted(grid_s, times_s, side="right") - 1, 0, len(grid_s) - 1)
    return values[idx]


def coach_day_logs(
    plan: CoachDay,
    col: int,
    result,
    ops,
    params: CoachParams,
    rng: np.random.Generator,
) -> dict[str, pd.DataFrame]:
    """The canonical HVAC, weather and trips tables of one simulated coach-day (no defects)."""
    campaign = plan.campaign
    n = round((plan.end - plan.start).total_seconds() / SIM_DT_S)
    grid = _seconds(pd.DatetimeIndex([plan.start]))[0] + np.arange(n) * SIM_DT_S
    env = result.env

    times = _sample_times(plan.start, plan.end, campaign.hvac_period_s)
    ts = _seconds(times)
    true_room = np.column_stack([_interp(ts, grid, result.states_c[:n, col, d]) for d in range(3)])
    noisy = true_room + rng.normal(size=true_room.shape) * params.sensor_noise_k
    q = params.sensor_quantum_k
    measured = np.round(noisy / q) * q if q > 0 else noisy
    mode = _hold(ts, grid, env.mode[:n, col])
    hvac = pd.DataFrame(
        {
            "time": times,
            "mode": [MODE_NAMES[int(m)] for m in mode],
            "t_ref_c": _hold(ts, grid, result.t_ref_c[:n, col]),
            "t_room_up_c": measured[:, 0],
            "t_room_mid_c": measured[:, 1],
            "t_room_low_c": measured[:, 2],
            "speed_kmh": _interp(ts, grid, env.speed_kmh[:n, col]),
            "p_hvac_kw": _metered_kw(
                ts, grid, result.total_power_w[:n, col], campaign.hvac_period_s
            ),
        }
    )

    wtimes = _sample_times(plan.start, plan.end, campaign.weather_period_s)
    ws = _seconds(wtimes)
    lat = _interp(ws, grid, ops.latitude_deg[:n])
    lon = _interp(ws, grid, ops.longitude_deg[:n])
    sun = _solar_at(wtimes, lat, lon)
    weather = pd.DataFrame(
        {
            "time": wtimes,
            "latitude_deg": lat,
            "longitude_deg": lon,
            "t_amb_c": _interp(ws, grid, env.t_amb_c[:n, col]),
            "ghi_w_m2": _interp(ws, grid, env.ghi_w_m2[:n, col]),
            "solar_elevation_deg": sun["elevation_deg"].to_numpy(),
            "solar_azimuth_deg": sun["azimuth_deg"].to_numpy(),
        }
    )
    trips = _trips(ops, n, plan.train, plan.line if plan.in_service else "")
    return {"hvac": hvac, "weather": weather, "trips": trips}


def _metered_kw(
    times_s: np.ndarray, grid_s: np.ndarray, power_w: np.ndarray, period_s: float
) -> np.ndarray:
    """A power meter's readings at ``times_s``: the mean of the simulated power (held over each
    step of ``grid_s``) over [t, t + ``period_s``), in kW at :data:`POWER_QUANTUM_KW`."""
    dt = grid_s[1] - grid_s[0]
    edges = np.append(grid_s, grid_s[-1] + dt)
    energy = np.concatenate([[0.0], np.cumsum(power_w * dt)])  # exact for a held power
    mean_w = (np.interp(times_s + period_s, edges, energy) - np.interp(times_s, edges, energy)) / (
        np.minimum(times_s + period_s, edges[-1]) - times_s
    )
    return np.round(mean_w / 1e3 / POWER_QUANTUM_KW) * POWER_QUANTUM_KW


def _solar_at(times: pd.DatetimeIndex, lat: np.ndarray, lon: np.ndarray) -> pd.DataFrame:
    """Solar elevation and azimuth at each (time, position) — pvlib accepts position arrays."""
    import pvlib

    sp = pvlib.solarposition.get_solarposition(times, lat, lon, altitude=420.0)
    return pd.DataFrame(
        {
            "elevation_deg": sp["apparent_elevation"].to_numpy(),
            "azimuth_deg": sp["azimuth"].to_numpy(),
        }
    )


@dataclass
class GenerationSummary:
    """What :func:`generate` wrote."""

    files: int = 0
    rows: int = 0
    coach_days: int = 0
    coach_days_logged: int = 0
    #: the files made unreadable on purpose (the defect ``Defects.unreadable_file``)
    corrupted: list[str] = field(default_factory=list)


def generate(
    out: str | Path,
    *,
    campaigns: tuple[Campaign, ...] = (WINTER_SPRING, SUMMER),
    max_days: int | None = None,
    max_coaches: int | None = None,
    defects: Defects | None = None,
    batch_size: int = 24,
    rule: RuleCurve | None = None,
    progress: Callable[[int], None] | None = None,
    coach_params: CoachParams | None = None,
) -> GenerationSummary:
    """Write the raw logs of ``campaigns`` under ``out`` (see the module docstring).

    ``max_days`` / ``max_coaches`` keep only the first days and coaches of each campaign (for
    tests and quick looks); ``defects`` the defect rates (default :class:`Defects`);
    ``progress`` is called with the number of coach-days done after each batch;
    ``coach_params`` makes every coach use those parameters instead of the fleet's spread
    (:func:`fleet_params`) — a known truth to calibrate against. The same arguments always
    write the same files.
    """
    rates = defects or Defects()
    out = Path(out)
    params = fleet_params() if coach_params is None else [coach_params] * len(fleet_params())
    summary = GenerationSummary()
    for campaign in campaigns:
        weather = campaign_weather(campaign)
        days = campaign.days[:max_days] if max_days else campaign.days
        n_coaches = min(len(campaign.coaches), max_coaches or len(campaign.coaches))
        plans = [
            plan_day(campaign, c, d, rates) for d in range(len(days)) for c in range(n_coaches)
        ]
        summary.coach_days += len(plans)
        plans = [p for p in plans if p.logged]
        summary.coach_days_logged += len(plans)
        sun_cache: dict[str, pd.DataFrame] = {}
        for b in range(0, len(plans), batch_size):
            batch = plans[b : b + batch_size]
            _simulate_and_write(
                batch, campaign, weather, params, rates, rule, out, sun_cache, summary
            )
            if progress:
                progress(len(batch))
    return summary


def simulate_coach_days(
    batch: list[CoachDay],
    weather: dict[str, Weather],
    params: list[CoachParams],
    rule: RuleCurve | None = None,
    sun_cache: dict[str, pd.DataFrame] | None = None,
):
    """Simulate coach-days side by side (one vectorised fleet, each column its own day).

    Returns the :class:`~trainclimate.sim.simulator.SimulationResult` (column j is
    ``batch[j]``, on ``DAY_HOURS_MAX`` hours from its own 03:00 local), each coach-day's
    operation series, and the coach parameters used.
    """
    site = SITES["zurich"]
    sun_cache = {} if sun_cache is None else sun_cache
    envs, opss = [], []
    for plan in batch:
        times = pd.date_range(
            plan.start, periods=int(DAY_HOURS_MAX * 3600 / SIM_DT_S), freq=f"{SIM_DT_S:g}s"
        )
        if plan.day not in sun_cache:
            sun_cache[plan.day] = solar_position(
                times, site.latitude_deg, site.longitude_deg, site.altitude_m
            )
        env, ops = _environment(plan, weather[plan.train], sun_cache[plan.day], times)
        envs.append(env)
        opss.append(ops)
    coach_params = [params[p.campaign.param_offset + p.coach_index] for p in batch]
    offsets = np.column_stack([driver_offset(p, e.time) for p, e in zip(batch, envs, strict=True)])
    sim = FleetSimulator(
        coach_params, Environment.side_by_side(envs), rule=rule, seed=batch[0].seed
    )
    sim.run(lambda k, s: s.t_rule(k) + offsets[k])
    return sim.result(), opss, coach_params


def _simulate_and_write(batch, campaign, weather, params, rates, rule, out, sun_cache, summary):
    result, opss, coach_params = simulate_coach_days(batch, weather, params, rule, sun_cache)
    for col, plan in enumerate(batch):
        rng = np.random.default_rng([plan.seed, 1])
        logs = coach_day_logs(plan, col, result, opss[col], coach_params[col], rng)
        for source, table in logs.items():
            exported = to_export(table, source, campaign.fmt)
            times = pd.DatetimeIndex(table["time"]) if "time" in table else pd.DatetimeIndex([])
            if source == "hvac":
                meter = np.random.default_rng([plan.seed, 2])
                exported = power_dropouts(exported, times, campaign.fmt, rates, meter)
            exported, unreadable = add_defects(exported, times, source, campaign.fmt, rates, rng)
            path = log_path(out, campaign.name, source, plan.train, plan.coach, plan.day)
            if unreadable:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(bytes(rng.integers(0, 256, 512, dtype=np.uint8)))
                summary.corrupted.append(str(path))
            else:
                write_export(exported, path, campaign.fmt)
            summary.files += 1
            summary.rows += len(exported)
