"""The twin's held-out score on setpoint changes: the changes found in the logged T_ref, the
score of a twin that is the truth and of one that responds wrongly, and the warnings."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from trainclimate.data.trajectory import Trajectory
from trainclimate.sim.params import CoachParams
from trainclimate.twin import response
from trainclimate.twin.knobs import apply
from trainclimate.twin.replay import replay, simulate


def test_changes_are_found_from_the_steps_of_the_logged_setpoint():
    minutes = 700
    # the rule's own T_ref creeps (0.002 K/min), far below a step
    u = 22.0 + 0.002 * np.arange(minutes)
    u[150:210] += 1.0  # +1 K for 60 min
    u[330:370] -= 2.0  # −2 K for 40 min, replaced by +0.5 K until 430
    u[370:430] += 0.5
    u[450:470] += 1.5  # +1.5 K, 20 min after the one before: the same change
    u[600:] -= 0.5  # −0.5 K until the trajectory's end
    found = response.changes_in(u, column=3)
    assert [(c.column, c.start, c.end, c.stop) for c in found] == [
        (3, 150, 210, 210 + response.SETTLE_MIN),
        (3, 330, 470, 470 + response.SETTLE_MIN),
        (3, 600, minutes, minutes),
    ]
    # a step's size is the minute's difference, the creep's 0.002 K included
    assert [c.size for c in found] == pytest.approx([1.002, -1.998, -0.498])
    # the window is cut at WINDOW_MAX_MIN after the first step
    long = np.full(minutes, 22.0)
    long[100:500] = 24.0
    (c,) = response.changes_in(long)
    assert (c.start, c.end, c.stop) == (100, 500, 100 + response.WINDOW_MAX_MIN)
    assert response.changes_in(22.0 + 0.002 * np.arange(minutes)) == []


def _winter_trajectory(steps: list[tuple[int, int, float]], minutes: int = 600) -> Trajectory:
    """A coach travelling at −5 °C, half full, without sun, its T_ref moved by ``steps``
    (start, end, offset K); its power not yet logged."""
    u = np.full(minutes, 22.0)
    for a, b, offset in steps:
        u[a:b] += offset
    d = np.tile([-5.0, 0.0, 0.0, 50.0, 60.0], (minutes, 1))
    time = pd.date_range("2022-02-24 06:00", periods=minutes, freq="1min", tz="UTC")
    return Trajectory(time=time, y=np.full((minutes, 3), 21.0), u=u[:, None], d=d)


#: Three changes of 60 min, each with its minutes before past the warm-up and apart.
THREE = [(120, 180, 2.0), (300, 360, -1.5), (480, 540, 1.0)]


@pytest.fixture(scope="module")
def logged():
    """The replay of :data:`THREE`, its power logged from the default coach, and the power of
    the default coach and of one with three times its thermal capacities (the same energy at a
    steady setpoint, a slower and larger response to a change)."""
    rep = replay([_winter_trajectory(THREE)])
    truth, wrong = CoachParams(), apply(CoachParams(), {"capacity_scale": 3.0})
    _, p = simulate(rep, [truth, wrong])
    return dataclasses.replace(rep, p_kw=p[:, :1].copy()), p[:, :1], p[:, 1:]


def test_a_twin_that_is_the_truth_scores_no_error(logged):
    rep, truth, _ = logged
    s = response.score(rep, truth)
    assert (s["changes"], s["scored"]) == (3, 3)
    assert s["minutes"] == 3 * (60 + response.SETTLE_MIN)
    assert s["energy_error_pct"] == pytest.approx(0.0, abs=1e-9)
    assert s["response_error_pct"] == pytest.approx(0.0, abs=1e-9)
    # raising T_ref by 2 K in winter costs energy; lowering it saves some
    sizes = [r["size_k"] for r in s["per_change"]]
    assert sizes == [2.0, -1.5, 1.0]
    assert [np.sign(r["logged_kwh"]) for r in s["per_change"]] == [1, -1, 1]
    assert s["response_logged_kwh"] > 1.0
    assert response.warnings(s) == []


def test_a_twin_with_a_wrong_response_is_warned_of(logged):
    rep, _, wrong = logged
    s = response.score(rep, wrong)
    # its energy over the changes' minutes is right, its response is not
    assert abs(s["energy_error_pct"]) < 1.0
    assert s["response_error_pct"] > 2 * response.MAX_RESPONSE_ERROR_PCT
    assert s["response_twin_kwh"] > 1.3 * s["response_logged_kwh"]
    (w,) = response.warnings(s)
    assert "energy response to the 3 held-out setpoint change(s)" in w
    assert f"{s['response_error_pct']:.0f} % off" in w


def test_no_setpoint_change_leaves_the_response_untested():
    rep = replay([_winter_trajectory([])])
    p = np.full(rep.p_kw.shape, 15.0)
    s = response.score(dataclasses.replace(rep, p_kw=p), p)
    assert (s["changes"], s["scored"], s["minutes"]) == (0, 0, 0)
    assert s["energy_error_pct"] is None and s["response_error_pct"] is None
    (w,) = response.warnings(s)
    assert w.startswith("the twin's response to a setpoint change is untested")
    assert "0 scored setpoint change(s) (0 found; 3 needed)" in w


def test_a_change_in_the_warm_up_is_found_but_not_scored(logged):
    # the last two changes as before, so the power logged and simulated for them holds
    rep, truth, wrong = logged
    rep = dataclasses.replace(replay([_winter_trajectory([(30, 90, 1.0), *THREE[1:]])]), p_kw=truth)
    s = response.score(rep, truth)
    assert (s["changes"], s["scored"], s["minutes"]) == (3, 2, 2 * (60 + response.SETTLE_MIN))
    train = {**s, "scored": 9, "response_error_pct": 12.0}
    (w,) = response.warnings(s, train)
    assert "2 scored setpoint change(s) (3 found; 3 needed)" in w
    assert w.endswith("; on the 9 scored changes of the training days its response is 12 % off")
    # too few and too far off: both said
    untested, off = response.warnings(response.score(rep, wrong))
    assert untested.startswith("the twin's response to a setpoint change is untested")
    assert "energy response to the 2 held-out setpoint change(s)" in off
