"""The decision policy on plain inputs, without a database: each decision wins over every one
after it (override, stale, inactive, guard tripped, not regular, no model, DDPC); what each
sets; the controller is asked for only when the DDPC step is reached; what the step is given
(the samples, a persistence forecast, T_rule over the horizon) and how its result becomes the
decision."""

from __future__ import annotations

from datetime import UTC, datetime
from types import SimpleNamespace

import numpy as np
import pytest

from trainclimate.control import DDPCController
from trainclimate.control.controller import REASONS, StepResult
from trainclimate.service.policy import Decision, decide
from trainclimate.service.settings import Settings
from trainclimate.service.store.telemetry import Samples

TICK = datetime(2024, 11, 28, 6, 0, tzinfo=UTC)
SETTINGS = Settings(database_url="sqlite://", sampling_min=5.0, stale_periods=2)
#: d over an interval: T_amb °C, Q_Gt, Q_Gs W/m², occupancy %, speed km/h.
D = np.array([1.5, 20.0, 10.0, 0.0, 0.0])
OK = StepResult(
    t_ref_c=21.7,
    source="ddpc",
    reason="ok",
    t_rule_c=22.0,
    t_opt_c=np.linspace(21.0, 22.0, 7),
    u_plan_c=np.full(7, 21.7),
    y_pred_c=np.zeros((6, 3)),
    solve_time_s=0.002,
    step_time_s=0.005,
)


def samples(
    *,
    t_rule: float = 22.0,
    u_prev: float = 21.5,
    regular: bool = True,
    age_min: float | None = 0.0,
    m: int = 3,
) -> Samples:
    """``m`` samples at the ticks up to TICK; the newest row ``age_min`` minutes before TICK
    (None: the coach never reported)."""
    times = TICK.timestamp() - 300.0 * np.arange(m)[::-1]
    return Samples(
        times_s=times,
        y=np.full((m, 3), 21.0),
        u=np.full(m - 1, 21.5),
        d_past=np.tile(D, (m - 1, 1)),
        d_now=D.copy() if m > 1 else None,
        u_prev=u_prev,
        t_rule_now=t_rule,
        regular=regular,
        last_time_s=None if age_min is None else TICK.timestamp() - 60.0 * age_min,
    )


class Recorder:
    """A stand-in controller: records each step's inputs and returns ``result``."""

    horizon = 6

    def __init__(self, result: StepResult = OK):
        self.result = result
        self.inputs: list[dict] = []

    def step(self, **inputs) -> StepResult:
        self.inputs.append(inputs)
        return self.result


class Controllers:
    """The controller factory the policy takes, counting how often it is asked."""

    def __init__(self, controller=None):
        self.controller = controller or Recorder()
        self.asked = 0

    def __call__(self):
        self.asked += 1
        return self.controller


def run(
    *,
    override: float | None = None,
    active: bool = True,
    controller: Controllers | None = None,
    settings: Settings = SETTINGS,
    guard: dict | None = None,
    **sample_args,
) -> Decision:
    coach = SimpleNamespace(id="A", ddpc_active=active)
    o = None if override is None else SimpleNamespace(id=7, t_ref_c=override)
    return decide(coach, samples(**sample_args), o, TICK, settings, controller, guard)


#: A tripped guard's figures.
GUARD = {"savings_pct": -12.3, "savings_ci95_pct": [-15.1, -9.6], "estimator": "crossover",
         "days": 8}  # fmt: skip


def test_each_decision_wins_over_the_ones_after_it():
    """Every condition at once gives the override; lifting them one at a time gives each later
    decision in turn, and with none left the DDPC step."""
    conditions = {
        "override": 23.0,
        "age_min": 30.0,
        "active": False,
        "guard": GUARD,
        "regular": False,
        "controller": None,
    }
    lifted = [
        ("override", None),
        ("age_min", 0.0),
        ("active", True),
        ("guard", None),
        ("regular", True),
        ("controller", Controllers()),
    ]
    got = []
    for lift in [None, *lifted]:
        if lift is not None:
            key, value = lift
            conditions[key] = value
        d = run(**conditions)
        got.append((d.source, d.reason))
    assert got == [
        ("override", "override"),
        ("fallback", "stale"),
        ("rule", "inactive"),
        ("rule", "costing_energy"),
        ("rule", "not_regular"),
        ("rule", "no_model"),
        ("ddpc", "ok"),
    ]


@pytest.mark.parametrize(
    ("conditions", "reason"),
    [
        ({"override": 22.5}, "override"),
        ({"age_min": 10.0}, "stale"),
        ({"active": False}, "inactive"),
        ({"guard": GUARD}, "costing_energy"),
        ({"regular": False}, "not_regular"),
    ],
)
def test_the_controller_is_asked_for_only_by_the_ddpc_step(conditions, reason):
    controllers = Controllers()
    assert run(controller=controllers, **conditions).reason == reason
    assert controllers.asked == 0
    assert run(controller=controllers).reason == "ok"
    assert controllers.asked == 1


def test_what_the_rule_decisions_set():
    assert run(active=False) == Decision(
        22.0, 22.0, "rule", "inactive", "the layer is off for this coach"
    )
    assert run(guard=GUARD) == Decision(
        22.0,
        22.0,
        "rule",
        "costing_energy",
        "the layer cost this pair energy: -12.3 % (95 % CI -15.1 to -9.6) over 8 service days "
        "(crossover); an operator re-enables it",
    )
    assert run(regular=False) == Decision(
        22.0, 22.0, "rule", "not_regular", "the HVAC is not in regular mode"
    )
    assert run() == Decision(
        22.0, 22.0, "rule", "no_model", "no predictor model yet (it is being prepared)"
    )


def test_an_override_is_clipped_to_the_band_around_t_rule_and_needs_one():
    inside = run(override=21.0)
    assert inside == Decision(21.0, 22.0, "override", "override", "override #7")
    assert run(override=25.0).t_ref_c == pytest.approx(24.0)  # T_rule + 2 K
    assert run(override=17.0).t_ref_c == pytest.approx(20.0)  # T_rule − 2 K
    assert run(override=23.0, age_min=30.0).source == "override"  # fresh rows not needed
    # without a T_rule there is nothing to clip to: stale, holding the T_ref applied last
    without = run(override=23.0, t_rule=float("nan"))
    assert (without.source, without.reason, without.t_ref_c, without.t_rule_c) == (
        "fallback",
        "stale",
        21.5,
        None,
    )


def test_stale_after_stale_periods_without_telemetry():
    """Stale when the newest row is ``stale_periods`` periods old (10 min) or more, or there is
    none: T_rule if known, else the T_ref applied last, else nothing to set."""
    assert run(age_min=9.0, active=False).reason == "inactive"
    stale = run(age_min=10.0, active=False)
    assert stale == Decision(22.0, 22.0, "fallback", "stale", "no telemetry for 2 sampling periods")
    three = Settings(database_url="sqlite://", sampling_min=5.0, stale_periods=3)
    assert run(age_min=10.0, active=False, settings=three).reason == "inactive"
    assert run(age_min=15.0, active=False, settings=three).reason == "stale"
    never = run(age_min=None, t_rule=float("nan"), u_prev=float("nan"))
    assert (never.source, never.reason, never.t_ref_c, never.t_rule_c) == (
        "fallback",
        "stale",
        None,
        None,
    )


def test_the_ddpc_step_gets_the_samples_a_persistence_forecast_and_t_rule():
    controllers = Controllers()
    s = samples()
    decision = decide(
        SimpleNamespace(id="A", ddpc_active=True), s, None, TICK, SETTINGS, controllers
    )
    (given,) = controllers.controller.inputs
    assert given["now_s"] == TICK.timestamp()
    np.testing.assert_array_equal(given["sample_times_s"], s.times_s)
    np.testing.assert_array_equal(given["y"], s.y)
    np.testing.assert_array_equal(given["u"], s.u)
    np.testing.assert_array_equal(given["d"], np.tile(D, (3, 1)))  # d_past, then d_now
    np.testing.assert_array_equal(given["d_future"], np.tile(D, (6, 1)))  # held over T = 6
    np.testing.assert_array_equal(given["t_rule"], np.full(7, 22.0))
    assert given["u_prev"] == 21.5
    assert decision == Decision(
        21.7,
        22.0,
        "ddpc",
        "ok",
        "",
        solve_time_ms=pytest.approx(2.0),
        step_time_ms=pytest.approx(5.0),
        predicted={
            "t_opt_c": np.linspace(21.0, 22.0, 7).tolist(),
            "u_plan_c": [21.7] * 7,
            "y_pred_c": [[0.0, 0.0, 0.0]] * 6,
        },
    )


def test_without_a_t_ref_applied_the_step_starts_from_t_rule_and_a_lone_sample_has_no_d():
    controllers = Controllers()
    run(controller=controllers, u_prev=float("nan"), m=1)
    (given,) = controllers.controller.inputs
    assert given["u_prev"] == 22.0
    assert given["d"].shape == (1, 5) and np.isnan(given["d"]).all()
    assert given["d_future"].shape == (6, 5) and np.isnan(given["d_future"]).all()


def test_the_controllers_own_fallback_is_passed_on_without_a_solve_time():
    fallback = StepResult(
        float("nan"), "fallback", "infeasible", 22.0, "no solution", step_time_s=0.001
    )
    d = run(controller=Controllers(Recorder(fallback)))
    assert d == Decision(
        None, 22.0, "fallback", "infeasible", "no solution", None, pytest.approx(1.0), None
    )


def test_a_real_controller_takes_the_policys_inputs():
    """The keyword inputs match :meth:`DDPCController.step`: a real controller (here without a
    predictor model) answers with its own fallback and reason, never an error."""
    controller = DDPCController(None, sampling_min=SETTINGS.sampling_min)
    d = run(controller=Controllers(controller))
    assert d.reason in REASONS and d.reason != "error", d
    assert d.solve_time_ms is None and d.step_time_ms is not None
