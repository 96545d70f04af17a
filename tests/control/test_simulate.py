"""``run_simulation``: a scenario under one controller, as a library call."""

import numpy as np
import pytest

from trainclimate.control.simulate import run_simulation
from trainclimate.sim.scenarios import ScenarioError


def test_rule_based_run_with_progress():
    seen = []
    run = run_simulation(
        "parked-heating-nov", coaches=2, hours=0.5, progress=lambda d, t: seen.append((d, t))
    )
    assert run.scenario.name == "parked-heating-nov" and run.ticks is None
    assert run.result.t_room_c.shape[1] == 2
    assert seen[-1][0] == seen[-1][1] == len(run.result.time)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)


def test_ddpc_run_keeps_the_band_and_reports_its_ticks(small_predictor):
    run = run_simulation("parked-heating-nov", "ddpc", hours=2.0, predictor=small_predictor)
    assert run.ticks is not None and run.ticks["ticks"] > 0
    rule, ref = run.result.t_rule_c[:, 0], run.result.t_ref_c[:, 0]
    assert np.all(np.abs(ref - rule) <= 2.0 + 1e-9)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="needs a prediction model"):
        run_simulation("parked-heating-nov", "ddpc", hours=0.5)
    with pytest.raises(ValueError, match="unknown controller"):
        run_simulation("parked-heating-nov", "pid", hours=0.5)
    with pytest.raises(ScenarioError):
        run_simulation("nope")
