"""The plausibility targets of docs/model.md ("Plausibility, as measured") for one half coach with
the default parameters."""

import numpy as np
import pandas as pd
import pytest

from trainclimate.analysis.summary import coach_kpis
from trainclimate.coach.rule import MODE_OFF, MODE_REGULAR
from trainclimate.sim import scenarios
from trainclimate.sim.environment import Environment
from trainclimate.sim.params import CoachParams
from trainclimate.sim.simulator import FleetSimulator


def constant_env(hours, t_amb, ghi=0.0, zenith=120.0, mode=MODE_REGULAR, dt=10.0):
    t = pd.date_range("2024-01-15", periods=int(hours * 3600 / dt), freq=f"{dt:g}s", tz="UTC")
    c = lambda v: np.full((len(t), 1), v, dtype=float)  # noqa: E731
    # sun abeam of the train: azimuth − heading = 90°
    return Environment(
        time=t,
        t_amb_c=c(t_amb),
        ghi_w_m2=c(ghi),
        zenith_deg=c(zenith),
        azimuth_deg=c(180.0),
        heading_deg=c(90.0),
        speed_kmh=c(0.0),
        occupancy_pct=c(0.0),
        door_open=c(0.0),
        mode=c(mode).astype(int),
    )


def steady_heat_w(t_amb, t_hold, **kw):
    """Thermal heat delivered (HVAC + floor/wall, W) over the last 6 h of 48 h held at t_hold."""
    sim = FleetSimulator(
        CoachParams(), constant_env(48.0, t_amb, **kw), initial_c=np.full(9, t_hold)
    )
    sim.run(lambda k, s: np.array([t_hold]))
    r = sim.result()
    last = slice(-6 * 360, None)
    np.testing.assert_allclose(r.t_room_c[last, 0].mean(axis=0), t_hold, atol=0.2)
    return float((r.q_hvac_w[last, 0].sum(-1) + r.q_fw_w[last, 0].sum(-1)).mean())


def test_heating_load_at_minus_five():
    q = steady_heat_w(-5.0, 20.0)
    assert 8e3 <= q <= 16e3


def test_cooling_load_in_summer_sun():
    q = -steady_heat_w(32.0, 26.0, ghi=800.0, zenith=35.0)
    assert 8e3 <= q <= 20e3


def test_cool_down_time_constant_with_hvac_off():
    sim = FleetSimulator(
        CoachParams(), constant_env(24.0, 0.0, mode=MODE_OFF), initial_c=np.full(9, 20.0)
    )
    sim.run()
    t_room = sim.result().t_room_c[:, 0].mean(axis=1)
    assert np.all(np.diff(t_room) <= 1e-12)  # monotone fall, no heating
    tau_h = np.argmax(t_room <= 20.0 * (1 - 0.632)) * 10.0 / 3600.0
    assert 1.0 <= tau_h <= 4.0


@pytest.mark.slow
def test_winter_day_energy():
    env, params = scenarios.build(scenarios.get("winter-day"))
    sim = FleetSimulator(params, env, seed=1)
    sim.run()
    kpis = coach_kpis(sim.result(), 0)
    assert 100.0 <= kpis["energy_kwh"] <= 350.0
    # the rule-based controller keeps the band most of the time in service
    assert kpis["avg_hourly_violation_k"] < 0.5
