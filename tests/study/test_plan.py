"""A fleet study's plan: its checks, its chunks, each coach-day's operation and the weather."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from trainclimate.sim.params import CoachParams
from trainclimate.sim.weather import SITES, generate_weather
from trainclimate.study.plan import (
    StudyError,
    StudySpec,
    check_weather,
    day_grid,
    plan_coach_day,
    study_weather,
)


def spec(n: int = 5, **kw) -> StudySpec:
    base = {
        "coach_ids": tuple(f"C{i}" for i in range(n)),
        "coach_params": (CoachParams().to_dict(),) * n,
        "start": "2025-01-13",
        "days": 10,
    }
    return StudySpec(**{**base, **kw})


def test_chunks_cover_every_coach_day_once():
    s = spec(7, days=10, chunk_coaches=3, chunk_days=4)
    seen = [(c, d) for ch in s.chunks() for c in range(ch.coach_lo, ch.coach_hi)
            for d in range(ch.day_lo, ch.day_hi)]  # fmt: skip
    assert len(s.chunks()) == 3 * 3
    assert sorted(seen) == [(c, d) for c in range(7) for d in range(10)]
    assert sum(ch.coach_days for ch in s.chunks()) == s.coach_days == 70
    assert len({ch.key for ch in s.chunks()}) == 9


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"days": 0}, "--days"),
        ({"start": "2025-13-45"}, "--start"),
        ({"controllers": ("ddpc",)}, "--controllers"),
        ({"controllers": ("rule", "edge")}, "--controllers"),
        ({"controllers": ("rule", "ddpc", "ddpc")}, "--controllers"),
        ({"parked_share": 1.5}, "--parked-share"),
        ({"occupancy_scale": -1.0}, "--occupancy-scale"),
        ({"coach_spread": 1.0}, "--coach-spread"),
        ({"chunk_days": 0}, "--chunk"),
        ({"forecast": "tomorrow"}, "--forecast"),
        ({"coach_ids": ("A", "A", "B", "C", "D")}, "unique"),
    ],
)
def test_a_bad_study_is_refused_with_its_reason(change, needle):
    with pytest.raises(StudyError, match=needle):
        spec(**change)


def test_the_fingerprint_follows_what_the_numbers_depend_on():
    s = spec()
    assert s.fingerprint() == spec().fingerprint()
    assert s.fingerprint() != dataclasses.replace(s, seed=1).fingerprint()
    assert s.fingerprint() != dataclasses.replace(s, chunk_days=3).fingerprint()
    assert s.fingerprint() != dataclasses.replace(s, model="other.npz:1").fingerprint()
    assert s.forecast == "persistence"  # what the service's controller gets
    assert s.fingerprint() != dataclasses.replace(s, forecast="perfect").fingerprint()


def test_coach_days_are_drawn_from_the_seed_alone_with_the_parked_share():
    s = spec(40, days=30, parked_share=0.3)
    plans = [plan_coach_day(s, c, d) for c in range(40) for d in range(30)]
    assert plans == [plan_coach_day(s, c, d) for c in range(40) for d in range(30)]
    share = np.mean([p.parked for p in plans])
    assert 0.25 < share < 0.35
    service = [p for p in plans if not p.parked]
    assert all(p.first_departure < p.last_arrival for p in service)
    assert len({p.line for p in service}) > 1
    assert all(plan_coach_day(spec(3, parked_share=1.0), c, 0).parked for c in range(3))


def test_each_coach_has_its_own_seeded_parameters():
    s = spec(3, coach_spread=0.15)
    a, b = s.params_of(0), s.params_of(1)
    assert a.to_dict() != b.to_dict()
    assert s.params_of(0).to_dict() == a.to_dict()
    ratio = np.asarray(a.c_room_j_k) / np.asarray(CoachParams().c_room_j_k)
    assert np.all((ratio >= 0.85) & (ratio <= 1.15))
    assert spec(3, coach_spread=0.0).params_of(1).to_dict() == CoachParams().to_dict()


def test_a_day_runs_from_three_to_three_local_time_across_daylight_saving():
    assert len(day_grid("2025-01-13")) == 24 * 360
    assert len(day_grid("2025-03-29")) == 23 * 360  # clocks go forward on the 30th, 02:00
    assert len(day_grid("2025-10-25")) == 25 * 360  # and back on the 26th, 03:00
    first = day_grid("2025-07-01")[0].tz_convert("Europe/Zurich")
    assert (first.hour, first.minute) == (3, 0)


def test_the_weather_must_cover_the_study():
    s = spec(days=3)
    check_weather(study_weather(s), s)
    short = generate_weather(
        SITES["zurich"], s.first_utc(), s.first_utc() + pd.Timedelta(days=1), seed=1
    )
    with pytest.raises(StudyError, match="--weather covers"):
        check_weather(short, s)
