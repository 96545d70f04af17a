"""The controller step: every fallback reason, the warm-up, and the safety of its output over a
sweep of valid and invalid inputs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from trainclimate.coach.rule import RuleCurve
from trainclimate.control import BandEdgeController, DDPCController, OCPSettings, Solution
from trainclimate.control import controller as controller_module
from trainclimate.control.coach_model import CoachModel
from trainclimate.control.controller import REASONS

RHO, T, PERIOD = 12, 6, 300.0
NOW = 1.7e9  # s since the epoch
RULE = RuleCurve()


@pytest.fixture(scope="module")
def model():
    return CoachModel(dt_s=PERIOD)


def window(trajectories, index: int, start: int, m: int = RHO + 1) -> dict:
    """A tick's inputs as the closed loop hands them over: m samples of a simulated coach ending
    at NOW, T_rule from the rule curve on the forecast T_amb, u(t−1) the last applied input."""
    traj = trajectories[index]
    y = traj.y[start : start + m]
    u = traj.u[start : start + m - 1, 0]
    d = traj.d[start : start + m]
    d_future = traj.d[start + m : start + m + T]
    return {
        "now_s": NOW,
        "sample_times_s": NOW - PERIOD * np.arange(m - 1, -1, -1),
        "y": y.copy(),
        "u": u.copy(),
        "d": d.copy(),
        "d_future": d_future.copy(),
        "t_rule": RULE(np.concatenate([[d[-1, 0]], d_future[:, 0]])),
        "u_prev": float(u[-1]),
    }


@pytest.fixture
def inputs(training_trajectories):
    """Valid inputs; u(t−1) 1.3 K above T_rule, so a fallback's expected output is exact:
    T_rule + 0.8 (one ΔT_max = 0.5 K step back toward T_rule)."""
    inp = window(training_trajectories, 4, 30)  # a parked coach, cold November morning
    inp["u_prev"] = float(inp["t_rule"][0] + 1.3)
    inp["u"][-1] = inp["u_prev"]
    return inp


def check_fallback(result, inp, reason, source="fallback"):
    assert result.reason == reason, result.detail
    assert result.source == source
    assert reason in REASONS
    rule0 = float(inp["t_rule"][0])
    assert result.t_rule_c == rule0
    # one rate-limited step from u(t−1) = T_rule + 1.3 back toward T_rule
    assert result.t_ref_c == pytest.approx(rule0 + 0.8, abs=1e-12)


def test_valid_inputs_give_the_ddpc_optimum(small_predictor, model, inputs):
    ctrl = DDPCController(small_predictor, model=model)
    result = ctrl.step(**inputs)
    assert (result.source, result.reason) == ("ddpc", "ok")
    assert result.solver_status == "solved"
    rule0, u_prev = inputs["t_rule"][0], inputs["u_prev"]
    assert abs(result.t_ref_c - u_prev) <= 0.5 + 1e-12
    assert abs(result.t_ref_c - rule0) <= 2.0 + 1e-12
    assert result.t_ref_c == pytest.approx(result.u_plan_c[0], abs=1e-6)
    assert result.t_opt_c.shape == (T + 1,) and result.y_pred_c.shape == (T, 3)
    assert result.step_time_s > 0 and np.isfinite(result.extra["objective"])


def test_warmup(small_predictor, model, inputs):
    short = {**inputs}
    for key in ("sample_times_s", "y", "d"):
        short[key] = inputs[key][-(RHO - 1) :]
    short["u"] = inputs["u"][-(RHO - 2) :]
    result = DDPCController(small_predictor, model=model).step(**short)
    check_fallback(result, inputs, "warmup", source="rule")


def test_stale_sample(small_predictor, model, inputs):
    ctrl = DDPCController(small_predictor, model=model)
    # one period late is still fresh; two periods is stale
    assert ctrl.step(**{**inputs, "now_s": NOW + PERIOD}).reason == "ok"
    check_fallback(ctrl.step(**{**inputs, "now_s": NOW + 2 * PERIOD}), inputs, "stale")


def test_missing_sample(small_predictor, model, inputs):
    gap = {**inputs}
    keep = np.r_[0:6, 7 : RHO + 1]  # sample 6 of the last ρ + 1 lost: ρ samples with a gap
    gap["sample_times_s"] = inputs["sample_times_s"][keep]
    gap["y"], gap["d"] = inputs["y"][keep], inputs["d"][keep]
    gap["u"] = inputs["u"][keep[:-1]]
    result = DDPCController(small_predictor, model=model).step(**gap)
    check_fallback(result, inputs, "missing_samples")


def _set(inp, key, index, value):
    arr = np.array(inp[key], dtype=float)
    arr[index] = value
    return {**inp, key: arr}


@pytest.mark.parametrize(
    "corrupt",
    [
        pytest.param(lambda i: _set(i, "y", (-1, 0), np.nan), id="y-nan"),
        pytest.param(lambda i: _set(i, "y", (3, 2), 75.0), id="y-out-of-range"),
        pytest.param(lambda i: _set(i, "d", (-1, 0), np.nan), id="d-nan"),
        pytest.param(lambda i: _set(i, "d", (5, 1), -20.0), id="d-negative-irradiance"),
        pytest.param(lambda i: _set(i, "d", (2, 0), 65.0), id="d-t-amb-out-of-range"),
        pytest.param(lambda i: _set(i, "d_future", (2, 0), np.inf), id="d-future-inf"),
        pytest.param(lambda i: _set(i, "d_future", (5, 3), 400.0), id="d-future-occupancy"),
        pytest.param(lambda i: {**i, "d_future": i["d_future"][:-1]}, id="d-future-too-short"),
        pytest.param(
            lambda i: {**i, "d_future": np.vstack([i["d_future"], i["d_future"][-1:]])},
            id="d-future-too-long",
        ),
        pytest.param(lambda i: _set(i, "u", 4, np.nan), id="u-nan"),
        pytest.param(lambda i: _set(i, "u", 2, 40.0), id="u-out-of-range"),
    ],
)
def test_invalid_data(small_predictor, model, inputs, corrupt):
    result = DDPCController(small_predictor, model=model).step(**corrupt(inputs))
    check_fallback(result, inputs, "invalid_data")


def test_nan_u_prev_falls_back_to_t_rule(small_predictor, model, inputs):
    result = DDPCController(small_predictor, model=model).step(**{**inputs, "u_prev": float("nan")})
    assert (result.reason, result.source) == ("invalid_data", "fallback")
    assert result.t_ref_c == inputs["t_rule"][0]


@pytest.mark.parametrize(
    "t_rule",
    [
        pytest.param(lambda r: np.where(np.arange(T + 1) == 3, np.nan, r), id="nan-later"),
        pytest.param(lambda r: r[:-1], id="too-short"),
        pytest.param(lambda r: np.append(r, r[-1]), id="too-long"),
    ],
)
def test_invalid_rule(small_predictor, model, inputs, t_rule):
    result = DDPCController(small_predictor, model=model).step(
        **{**inputs, "t_rule": t_rule(inputs["t_rule"])}
    )
    check_fallback(result, inputs, "invalid_rule")


def test_no_current_rule_holds_the_last_setpoint(small_predictor, model, inputs):
    for bad in (np.full(T + 1, np.nan), [], None, "warm"):
        result = DDPCController(small_predictor, model=model).step(**{**inputs, "t_rule": bad})
        assert (result.reason, result.source) == ("invalid_rule", "fallback")
        assert result.t_ref_c == inputs["u_prev"]


def test_no_predictor(model, inputs):
    result = DDPCController(None, model=model).step(**inputs)
    check_fallback(result, inputs, "no_predictor")


def test_incompatible_predictor(predictor_10min, model, inputs):
    ctrl = DDPCController(predictor_10min, model=model)
    assert ctrl.problem is None
    result = ctrl.step(**inputs)
    check_fallback(result, inputs, "incompatible_predictor")
    assert "10-min" in result.detail and "every 5 min" in result.detail


def test_incompatible_coach_model(small_predictor, inputs):
    result = DDPCController(small_predictor, model=CoachModel(dt_s=600.0)).step(**inputs)
    check_fallback(result, inputs, "incompatible_predictor")


def test_infeasible(small_predictor, model, inputs):
    """u(t−1) 3 K above T_rule: no u(0|t) meets both the rate limit and the band. OSQP says
    'primal infeasible'; the fallback obeys the band (the driver's limit) and so steps back
    2 × ΔT_max here: T_rule + 2."""
    inp = {**inputs, "u_prev": float(inputs["t_rule"][0] + 3.0)}
    inp["u"] = inputs["u"].copy()
    inp["u"][-1] = inp["u_prev"]
    result = DDPCController(small_predictor, model=model).step(**inp)
    assert (result.reason, result.source) == ("infeasible", "fallback")
    assert result.solver_status == "primal infeasible"
    assert result.t_ref_c == pytest.approx(inputs["t_rule"][0] + 2.0, abs=1e-12)


def test_infeasible_step_does_not_spoil_the_next(
    small_predictor, model, inputs, training_trajectories
):
    ctrl = DDPCController(small_predictor, model=model)
    inp = {**inputs, "u_prev": float(inputs["t_rule"][0] + 3.0)}
    assert ctrl.step(**inp).reason == "infeasible"
    nxt = window(training_trajectories, 4, 31)
    nxt["now_s"] = NOW + PERIOD
    nxt["sample_times_s"] = nxt["sample_times_s"] + PERIOD
    assert ctrl.step(**nxt).reason == "ok"


def test_solver_timeout(small_predictor, model, inputs):
    """OSQP stops at its time limit with status 'run time limit reached'."""
    ctrl = DDPCController(small_predictor, OCPSettings(time_limit_s=1e-9), model=model)
    result = ctrl.step(**inputs)
    assert result.solver_status == "run time limit reached"
    check_fallback(result, inputs, "solver_timeout")


def _fake_solve(status, solve_time_s=0.0):
    def solve(*args, **kwargs):
        nan = np.full((T, 3), np.nan)
        return Solution(np.full(T + 1, 21.0), nan, nan, 1.0, status, solve_time_s)

    return solve


def test_solved_too_late_is_a_timeout(small_predictor, model, inputs, monkeypatch):
    ctrl = DDPCController(small_predictor, model=model)
    monkeypatch.setattr(ctrl.problem, "solve", _fake_solve("solved", solve_time_s=0.2))
    check_fallback(ctrl.step(**inputs), inputs, "solver_timeout")


@pytest.mark.parametrize("status", ["maximum iterations reached", "solved inaccurate", "unsolved"])
def test_solver_failed(small_predictor, model, inputs, monkeypatch, status):
    ctrl = DDPCController(small_predictor, model=model)
    monkeypatch.setattr(ctrl.problem, "solve", _fake_solve(status))
    result = ctrl.step(**inputs)
    check_fallback(result, inputs, "solver_failed")
    assert result.solver_status == status and status in result.detail


@pytest.mark.parametrize("target", ["estimator", "t_opt", "solve"])
def test_unexpected_error(small_predictor, model, inputs, monkeypatch, target):
    ctrl = DDPCController(small_predictor, model=model)

    def boom(*args, **kwargs):
        raise RuntimeError("boom")

    if target == "estimator":
        monkeypatch.setattr(ctrl.estimator, "run", boom)
    elif target == "t_opt":
        monkeypatch.setattr(controller_module, "t_opt", boom)
    else:
        monkeypatch.setattr(ctrl.problem, "solve", boom)
    result = ctrl.step(**inputs)
    check_fallback(result, inputs, "error")
    assert result.detail == "RuntimeError: boom"


@pytest.mark.parametrize("u_prev", [None, "warm", [1.0, 2.0]])
def test_garbage_u_prev_never_raises(small_predictor, model, inputs, u_prev):
    result = DDPCController(small_predictor, model=model).step(**{**inputs, "u_prev": u_prev})
    assert result.source == "fallback"
    assert result.t_ref_c == inputs["t_rule"][0]  # nothing to limit the rate from


def test_warmup_tick_by_tick(small_predictor, model, training_trajectories):
    """Samples arrive one tick at a time, each output applied over the next interval: ticks
    1 … ρ−1 are the lead-in (T_ref = T_rule), tick ρ is the first DDPC step."""
    traj = training_trajectories[4]
    ctrl = DDPCController(small_predictor, model=model)
    results, applied = [], []
    for i in range(1, RHO + 4):
        keep = slice(max(0, i - (RHO + 1)), i)
        times = NOW + PERIOD * np.arange(i)
        t_rule = RULE(traj.d[i - 1 : i + T, 0])
        result = ctrl.step(
            now_s=times[-1],
            sample_times_s=times[keep],
            y=traj.y[keep],
            u=np.array(applied[-RHO:]),
            d=traj.d[keep],
            d_future=traj.d[i : i + T],
            t_rule=t_rule,
            u_prev=applied[-1] if applied else float(t_rule[0]),
        )
        results.append(result)
        applied.append(result.t_ref_c)
    assert [r.reason for r in results] == ["warmup"] * (RHO - 1) + ["ok"] * 4
    assert [r.source for r in results] == ["rule"] * (RHO - 1) + ["ddpc"] * 4
    assert [r.t_ref_c for r in results[: RHO - 1]] == [r.t_rule_c for r in results[: RHO - 1]]


# --- the output is always safe ---------------------------------------------------------------
CORRUPTIONS = (
    "none",
    "none",
    "none",
    "y-nan",
    "y-range",
    "d-range",
    "d-future-nan",
    "d-future-short",
    "u-range",
    "gap",
    "stale",
    "short",
    "rule-nan-later",
    "rule-short",
)


def corrupted(inp: dict, kind: str, where: int) -> dict:
    out = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in inp.items()}
    if kind == "y-nan":
        out["y"][where % (RHO + 1), where % 3] = np.nan
    elif kind == "y-range":
        out["y"][where % (RHO + 1), where % 3] = -45.0
    elif kind == "d-range":
        out["d"][where % (RHO + 1), 1 + where % 4] = -1.0
    elif kind == "d-future-nan":
        out["d_future"][where % T, where % 5] = np.nan
    elif kind == "d-future-short":
        out["d_future"] = out["d_future"][: where % T]
    elif kind == "u-range":
        out["u"][where % RHO] = 5.0
    elif kind == "gap":
        keep = np.delete(np.arange(RHO + 1), 1 + where % (RHO - 1))
        out["sample_times_s"], out["y"], out["d"] = (
            out["sample_times_s"][keep],
            out["y"][keep],
            out["d"][keep],
        )
        out["u"] = out["u"][keep[:-1]]
    elif kind == "stale":
        out["now_s"] += PERIOD * (2 + where % 5)
    elif kind == "short":
        n = 1 + where % (RHO - 1)
        for key in ("sample_times_s", "y", "d"):
            out[key] = out[key][-n:]
        out["u"] = out["u"][-(n - 1) :] if n > 1 else out["u"][:0]
    elif kind == "rule-nan-later":
        out["t_rule"][1 + where % T] = np.nan
    elif kind == "rule-short":
        out["t_rule"] = out["t_rule"][: 1 + where % T]
    return out


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    index=st.integers(0, 7),
    start=st.integers(0, 20),
    summer=st.booleans(),
    room=st.floats(-3.0, 3.0),
    amb=st.floats(-10.0, 20.0),
    u_prev=st.floats(-2.5, 2.5),
    kind=st.sampled_from(CORRUPTIONS),
    where=st.integers(0, 1000),
    conservative=st.booleans(),
)
def test_output_is_always_in_the_band_and_rate_limited(
    small_predictor, model, training_trajectories, index, start, summer, room, amb, u_prev, kind,
    where, conservative,
):  # fmt: skip
    """Whatever the inputs: T_ref within T_rule ± 2 K and within ΔT_max of u(t−1) (for any u(t−1)
    within ΔT_max of the band), no exception."""
    s = OCPSettings(t_max=0.5, du_max=0.3) if conservative else OCPSettings()
    inp = window(training_trajectories, index, start)
    shift = (amb + (16.0 if summer else 0.0)) - inp["d"][-1, 0]
    inp["d"][:, 0] += shift
    inp["d_future"][:, 0] += shift
    inp["t_rule"] = RULE(np.concatenate([[inp["d"][-1, 0]], inp["d_future"][:, 0]]))
    inp["y"] += inp["t_rule"][0] - inp["y"][-1].mean() + room
    inp["u"] += inp["t_rule"][0] - inp["u"][-1]
    inp["u_prev"] = float(inp["t_rule"][0] + u_prev / 2.5 * (s.u_band + s.du_max))
    inp["u"][-1] = inp["u_prev"]
    inp = corrupted(inp, kind, where)
    result = DDPCController(small_predictor, s, model=model).step(**inp)
    event(f"{kind} -> {result.reason}")
    rule0 = inp["t_rule"][0]
    assert abs(result.t_ref_c - rule0) <= s.u_band + 1e-9
    assert abs(result.t_ref_c - inp["u_prev"]) <= s.du_max + 1e-9
    assert result.reason in REASONS
    if kind == "none":
        assert result.reason == "ok"
    if result.reason != "ok":
        assert result.source == ("rule" if result.reason == "warmup" else "fallback")


def test_band_edge_controller_applies_t_opt(model, inputs):
    """The band-edge reference: T_ref = T_opt(1|t) straight, no model, no rate limit."""
    edge = BandEdgeController(model=model)
    result = edge.step(**inputs)
    assert (result.source, result.reason) == ("edge", "ok")
    # a cold November morning: T_opt(1|t) is the band's lower edge, applied at once
    assert result.t_opt_c[1] == pytest.approx(inputs["t_rule"][1] - 1.0)
    assert result.t_ref_c == result.t_opt_c[1]
    assert abs(result.t_ref_c - inputs["u_prev"]) > 0.5  # no rate limit
    # its inputs are checked like the DDPC layer's
    bad = _set(inputs, "y", (-1, 1), np.nan)
    check_fallback(edge.step(**bad), inputs, "invalid_data")
