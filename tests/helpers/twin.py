"""A calibrated twin's coach-params file, as ``calibrate`` writes it, for the tests of the
commands that read one."""

from __future__ import annotations

import json

from trainclimate.sim.params import CoachParams
from trainclimate.twin.validity import params_file


def twin_file(path, validated):
    """A calibrated twin's coach-params file at ``path`` validated for ``validated`` (°C)."""
    coach = {
        "coach": "124A",
        "params": CoachParams(fan_supply_w=1300.0).to_dict(),
        "validated_t_amb_c": validated,
        "fitted": {"fan_supply_w": {"value": 1300.0, "std": 20.0, "ci95": [1250.0, 1360.0]}},
        "not_identified": [{"param": "cop_level", "reason": "nothing depends on it"}],
        "warnings": [],
    }
    path.write_text(json.dumps(params_file(coach)))
    return path
