"""The calibrated knobs: the quantities :func:`~trainclimate.twin.calibration.calibrate` can fit
and how each changes a :class:`~trainclimate.sim.params.CoachParams` (a scale on default fields,
or a field itself).

Light on purpose (numpy and the coach parameters only): the twin's file
(:mod:`trainclimate.twin.validity`) moves a knob to its interval's end without loading the fit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from trainclimate.sim.params import CoachParams


class CalibrationError(ValueError):
    """The data cannot calibrate the parameters asked for: too little, or not informative."""


@dataclass(frozen=True)
class Knob:
    """A calibrated quantity: its ``bounds``, its nominal value and the unit of ``value``."""

    bounds: tuple[float, float]
    unit: str
    description: str


#: The parameters :func:`~trainclimate.twin.calibration.calibrate` can fit, each a scale on
#: default fields or a field itself.
CALIBRATED = {
    "envelope_scale": Knob(
        (0.3, 3.0),
        "–",
        "the envelope's U·A: deck air to outer chassis and outer chassis to outside air "
        "(the outer entries of ua_room_chassis_w_k and area_ext_m2 ×)",
    ),
    "capacity_scale": Knob(
        (0.3, 3.0), "–", "every thermal capacity: room air, inventory, chassis (c_*_j_k ×)"
    ),
    "solar_scale": Knob(
        (0.0, 3.0), "–", "solar aperture: roof and side absorptance, window g-value (×)"
    ),
    "cop_level": Knob((0.3, 3.0), "–", "the compressor's COP at every temperature (cop_* ×)"),
    "fan_supply_w": Knob((100.0, 5000.0), "W", "supply fans' power while the unit runs"),
    "fresh_air_base_fraction": Knob((0.02, 0.6), "–", "base fresh-air share of the supply air"),
}
#: The default subset: every knob, each kept at its base value where the data do not identify it.
DEFAULT_PARAMS = tuple(CALIBRATED)

#: The entries of ``ua_room_chassis_w_k`` (deck rows, chassis columns) through the outer
#: envelope: the upper deck to the upper chassis, the middle deck to the upper and lower
#: chassis, the lower deck to the lower chassis (not the middle floor's interior film).
_OUTER = np.array([[True, False, False], [True, False, True], [False, False, True]])


#: The calibrated quantities set to their value; the others are scales of the base parameters.
QUANTITIES = ("fan_supply_w", "fresh_air_base_fraction")


def apply(base: CoachParams, values: dict[str, float]) -> CoachParams:
    """``base`` with the calibrated quantities ``values`` (name → value, :data:`CALIBRATED`)."""
    changes: dict[str, object] = {}
    for name, v in values.items():
        if name == "envelope_scale":
            changes["area_ext_m2"] = base.area_ext_m2 * v
            changes["ua_room_chassis_w_k"] = np.where(_OUTER, v, 1.0) * base.ua_room_chassis_w_k
        elif name == "capacity_scale":
            for field in ("c_room_j_k", "c_inv_j_k", "c_chassis_j_k"):
                changes[field] = getattr(base, field) * v
        elif name == "solar_scale":
            for field in ("roof_absorptance", "side_absorptance", "window_g"):
                changes[field] = getattr(base, field) * v
        elif name == "cop_level":
            for field in ("cop_a", "cop_b", "cop_min", "cop_max", "cop_carnot_efficiency"):
                changes[field] = getattr(base, field) * v
        elif name in QUANTITIES:
            changes[name] = float(v)
        else:
            raise CalibrationError(f"unknown calibration parameter {name!r}")
    return dataclasses.replace(base, **changes)


def nominal(base: CoachParams, name: str) -> float:
    """The value of calibrated quantity ``name`` in ``base`` (scales: 1)."""
    return float(getattr(base, name)) if name in QUANTITIES else 1.0
