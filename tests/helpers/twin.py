"""A calibrated twin's coach-params file, as ``calibrate`` writes it, for the tests of the
commands that read one."""

from __future__ import annotations

import json

from trainclimate.sim.params import CoachParams
from trainclimate.twin.validity import params_file

#: A held-out score of the setpoint changes that validates the twin's response.
RESPONSE_OK = {"changes": 5, "scored": 4, "minutes": 560, "response_error_pct": 8.0}


def twin_file(path, validated, response=RESPONSE_OK):
    """A calibrated twin's coach-params file at ``path`` validated for ``validated`` (°C),
    whose score on the held-out days' setpoint changes is ``response``."""
    coach = {
        "coach": "124A",
        "params": CoachParams(fan_supply_w=1300.0).to_dict(),
        "validated_t_amb_c": validated,
        "fitted": {"fan_supply_w": {"value": 1300.0, "std": 20.0, "ci95": [1250.0, 1360.0]}},
        "not_identified": [{"param": "cop_level", "reason": "nothing depends on it"}],
        "holdout": {"energy_error_pct": -1.2, "setpoint_response": response},
        "warnings": [],
    }
    path.write_text(json.dumps(params_file(coach)))
    return path
