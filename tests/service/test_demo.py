"""The demo fleet driven directly (no server, SQLite): its trains and their pairing, and the
afternoon of its first day, 12:30–15:00 local (30 periods, ≈ 4 s): D9-A's daily connection loss
(14:00–14:40) leaves it on T_rule while the DDPC setpoints issued for it do not arrive, and on D8's
mild day heating and cooling alternate. Four trains run a crossover trial from the demo's first
moment, and at 03:00 of the second day their other coach takes the layer. A simulator state
stored by a fleet of another size (by the three-train demo of earlier versions) starts the coaches
afresh instead of failing every period.
"""

from __future__ import annotations

import logging
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sqlalchemy import func, select

from trainclimate.coach.states import MIXED
from trainclimate.service.adapters import demo
from trainclimate.service.app import register_model_file
from trainclimate.service.scheduler import Scheduler
from trainclimate.service.settings import Settings
from trainclimate.service.store import plans
from trainclimate.service.store.db import Database, migrate
from trainclimate.service.store.models import (
    Coach,
    FleetClock,
    Setpoint,
    Telemetry,
    Train,
    TrainPlan,
    TrialDay,
)
from trainclimate.service.store.telemetry import load_frame
from trainclimate.sim import scenarios
from trainclimate.sim.simulator import FleetSimulator

TRAINS = {t.id: t for t in demo.TRAINS}
PERIOD = timedelta(minutes=5)


def local(clock: str) -> datetime:
    """Local ``"HH:MM"`` on the demo's first day, in UTC."""
    day = demo.START_LOCAL.split()[0]
    return pd.Timestamp(f"{day} {clock}", tz=demo.LOCAL_TZ).tz_convert("UTC").to_pydatetime()


def demo_fleet(home: Path, model_file: Path) -> demo.DemoFleet:
    """The demo fleet registered on a fresh SQLite database with the small model."""
    url = f"sqlite:///{home / 'trainclimate.db'}"
    settings = Settings(database_url=url, predictor_path=model_file)
    migrate(url)
    db = Database(url)
    with db.transaction() as session:
        register_model_file(session, settings)
        demo.register(session)
    return demo.DemoFleet(db, Scheduler(db, settings), speedup=300)


@pytest.fixture(scope="module")
def afternoon(tmp_path_factory, small_predictor_file):
    """The fleet run from 12:30 to 15:00 local: the activated coaches' layer has its hour of
    lead-in by 13:30 and issues DDPC setpoints from then on."""
    fleet = demo_fleet(tmp_path_factory.mktemp("demo"), small_predictor_file)
    with fleet.db.transaction() as session:
        session.get(FleetClock, demo.FLEET).time = local("12:30")
    while fleet.advance() < local("15:00"):
        pass
    yield fleet
    fleet.db.dispose()


def test_at_least_ten_trains_of_an_activated_and_a_deactivated_coach(afternoon):
    with afternoon.db.transaction() as session:
        trains = dict(session.execute(select(Train.id, Train.name)).all())
        coaches = session.scalars(select(Coach).where(Coach.fleet == demo.FLEET)).all()
    assert len(trains) >= 10 and len(coaches) == 2 * len(trains) >= 20
    pairing = {(c.id, c.train_id, c.ddpc_active) for c in coaches}
    assert pairing == {(f"{t}-{side}", t, side == "A") for t in trains for side in "AB"}
    assert sorted(demo.coach_ids()) == sorted(c.id for c in coaches)
    assert len(set(trains.values())) == len(trains)  # each name says where its train is
    assert trains["D1"] == "parked outdoors in Zug (like Experiment 4)"


def test_four_trains_run_a_crossover_trial_from_the_first_moment(tmp_path, small_predictor_file):
    """D2, D3, D7 alternate and D5 randomized, in force from the demo's start (audited as the
    demo); registering again adds nothing. Run across 03:00 of the second day, their coach B
    takes the layer at the 03:00 tick, and the days are recorded."""
    fleet = demo_fleet(tmp_path, small_predictor_file)
    start = pd.Timestamp(demo.START_LOCAL, tz=demo.LOCAL_TZ).tz_convert("UTC")
    with fleet.db.transaction() as session:
        demo.register(session)  # a restart
        rows = session.scalars(select(TrainPlan).order_by(TrainPlan.train_id)).all()
        assert [(r.train_id, r.plan, r.switch_hour, r.seed) for r in rows] == [
            ("D2", "alternate", 3, 0),
            ("D3", "alternate", 3, 0),
            ("D5", "randomized", 3, 0),
            ("D7", "alternate", 3, 0),
        ]
        assert {r.effective_from for r in rows} == {start} and {r.created_by for r in rows} == {
            "demo"
        }
        names = plans.names_in_force(session, session.scalars(select(Train)).all())
    assert {t for t, plan in names.items() if plan != "fixed"} == {"D2", "D3", "D5", "D7"}
    assert {t.id for t in demo.TRAINS if t.plan != "fixed"} == {"D2", "D3", "D5", "D7"}

    switch = pd.Timestamp("2024-11-29 03:00", tz=demo.LOCAL_TZ).tz_convert("UTC")
    with fleet.db.transaction() as session:
        session.get(FleetClock, demo.FLEET).time = (switch - 2 * PERIOD).to_pydatetime()
    while fleet.advance() < switch + PERIOD:
        pass
    with fleet.db.transaction() as session:
        reasons = dict(
            session.execute(
                select(Setpoint.coach_id, Setpoint.reason).where(Setpoint.tick == switch)
            ).all()
        )
        days = session.scalars(select(TrialDay).where(TrialDay.plan != "fixed")).all()
        layer = dict(session.execute(select(Coach.id, Coach.ddpc_active)).all())
    for t in ("D2", "D3", "D5", "D7"):
        assert (reasons[f"{t}-A"], layer[f"{t}-A"], layer[f"{t}-B"]) == ("inactive", False, True)
        assert reasons[f"{t}-B"] != "inactive"
    for t in ("D1", "D4", "D6", "D8", "D9", "D10"):
        assert reasons[f"{t}-B"] == "inactive" and layer[f"{t}-A"], t
    recorded = {(d.train_id, d.day.isoformat(), d.activated_coach_id) for d in days}
    assert recorded == {
        (t, day, f"{t}-{side}")
        for t in ("D2", "D3", "D5", "D7")
        for day, side in (("2024-11-28", "A"), ("2024-11-29", "B"))
    }
    fleet.db.dispose()


def test_a_lost_connection_leaves_the_coach_on_t_rule_and_its_twin_connected(afternoon):
    assert TRAINS["D9"].connection_loss == ("14:00", "14:40")
    start, end = (local(clock) for clock in TRAINS["D9"].connection_loss)
    with afternoon.db.transaction() as session:
        a, b = (
            load_frame(session, cid, local("12:30"), local("15:00")) for cid in ("D9-A", "D9-B")
        )
        issued = {
            tick: (t_ref, t_rule)
            for tick, t_ref, t_rule in session.execute(
                select(Setpoint.tick, Setpoint.t_ref_c, Setpoint.t_rule_c).where(
                    Setpoint.coach_id == "D9-A", Setpoint.source == "ddpc"
                )
            )
        }
        disconnected = session.scalar(select(func.count()).where(Telemetry.connected.is_(False)))
    lost = (a.index > start) & (a.index <= end)  # a row covers the minute up to its time
    assert lost.sum() == 40 and disconnected == 40  # no other coach, no other minute
    assert not a["connected"][lost].astype(bool).any()
    assert a["connected"][~lost].astype(bool).all() and b["connected"].astype(bool).all()
    # the layer's setpoints for the loss were issued, away from T_rule, but never applied
    during = a[lost]
    assert (during["t_ref_c"] == during["t_rule_c"]).all()
    ticks = [t for t in sorted(issued) if start <= t < end]
    assert ticks == [start + i * PERIOD for i in range(8)]
    assert all(issued[t][0] < issued[t][1] for t in ticks)
    # before it (the layer active from 13:30) and after it the coach follows them
    for window in ((a.index > local("13:35")) & (a.index <= start), a.index > end):
        assert (a["t_ref_c"][window] < a["t_rule_c"][window]).all()


def test_on_the_mild_day_heating_and_cooling_alternate(afternoon):
    sim = afternoon.sim
    run = slice(int(np.searchsorted(sim.env.time, pd.Timestamp(local("12:30")))), sim.k)
    result = sim.result()
    heating = result.power_w["heater"][run] + result.power_w["floor_wall"][run]
    cooling = result.power_w["compressor"][run]
    for cid in ("D8-A", "D8-B"):
        c = afternoon.ids.index(cid)
        assert (result.hvac_state[run, c] == MIXED).any(), cid
        assert (heating[:, c] > 0).any() and (cooling[:, c] > 0).any(), cid
        # a deck's unit switches between heating and cooling, back and forth
        sign = np.sign(result.q_hvac_w[run, c, 1])
        assert (np.diff(sign[sign != 0]) != 0).sum() >= 10, cid
    # on the cold day the other parked trains only heat
    for cid in ("D1-A", "D1-B", "D3-A", "D7-A"):
        c = afternoon.ids.index(cid)
        assert (heating[:, c] > 0).any() and (cooling[:, c] == 0).all(), cid


def test_a_state_stored_by_a_fleet_of_another_size_starts_the_coaches_afresh(
    tmp_path, small_predictor_file, caplog
):
    fleet = demo_fleet(tmp_path, small_predictor_file)
    env, params = scenarios.build(scenarios.get("parked-heating-nov"), n_coaches=6, hours=1.0)
    with fleet.db.transaction() as session:
        session.get(FleetClock, demo.FLEET).state = FleetSimulator(params, env).snapshot()
    with caplog.at_level(logging.WARNING, logger=demo.__name__):
        t1 = fleet.advance()
    n = len(demo.coach_ids())
    assert f"the stored demo state is of 6 coaches, the fleet has {n}" in caplog.text
    with fleet.db.transaction() as session:
        assert len(session.get(FleetClock, demo.FLEET).state["T"]) == n
        reported = session.scalars(select(Telemetry.coach_id).where(Telemetry.time == t1)).all()
    assert sorted(reported) == sorted(demo.coach_ids())
    fleet.db.dispose()


def test_the_demo_fleet_takes_a_calibrated_coachs_parameters(tmp_path, small_predictor_file):
    """Every demo coach simulated with the parameters given (e.g. ``calibrate --out``), not its
    scenario's: a coach with twice the envelope loses more heat on the same day."""
    from trainclimate.sim.params import CoachParams
    from trainclimate.twin.knobs import apply

    fleet = demo_fleet(tmp_path, small_predictor_file)
    day = pd.Timestamp(demo.START_LOCAL.split()[0], tz=demo.LOCAL_TZ)
    own, _ = fleet._build_day(day)
    leaky = apply(CoachParams(), {"envelope_scale": 2.0})
    fleet.coach_params = leaky
    given, _ = fleet._build_day(day)
    assert all(p.to_dict() == leaky.to_dict() for p in _unstacked(given))
    assert not any(p.to_dict() == leaky.to_dict() for p in _unstacked(own))
    fleet.db.dispose()


def _unstacked(sim: FleetSimulator):
    """The simulator's per-coach parameter sets."""
    import dataclasses

    from trainclimate.sim.params import CoachParams

    n = sim.env.n_coaches
    return [
        CoachParams(**{f.name: getattr(sim.p, f.name)[i] for f in dataclasses.fields(CoachParams)})
        for i in range(n)
    ]


def test_a_twin_validated_for_summer_is_warned_of_on_a_november_day(
    tmp_path, small_predictor_file, caplog
):
    """The demo's cold November days leave a twin validated at 15–32 °C: each train's day is
    logged once as extrapolated; a twin validated for the cold is not."""
    fleet = demo_fleet(tmp_path, small_predictor_file)
    day = pd.Timestamp(demo.START_LOCAL.split()[0], tz=demo.LOCAL_TZ)
    fleet.validated_t_amb_c = [-20.0, 25.0]
    with caplog.at_level("WARNING"):
        fleet._build_day(day)
    assert "validated range" not in caplog.text
    fleet.validated_t_amb_c = [15.0, 32.0]
    with caplog.at_level("WARNING"):
        fleet._build_day(day)
    warned = [m for m in caplog.messages if "validated range 15 to 32" in m]
    assert len(warned) == len(demo.TRAINS)
    assert warned[0].startswith(f"demo train {demo.TRAINS[0].id} on {day:%Y-%m-%d}: T_amb ")
    fleet.db.dispose()
