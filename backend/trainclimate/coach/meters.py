"""The coach's electrical meters: what each counts, which one the headline savings use, and how
they are named.

Each meter is a sum of the HVAC's electrical power components (``heater``, ``floor_wall``,
``compressor``, ``fans``: the ``*_w`` fields of :class:`trainclimate.sim.power.Power`), the
quantity every energy saving is measured in.
"""

from __future__ import annotations

#: What each meter counts, by component: ``hvac`` the HVAC units alone (heater, compressor,
#: fans) — what the paper's external loggers measured (Section V); ``hvac_and_floor`` adds the
#: floor and wall heating, a system beside the HVAC set by its state and T_amb, not by T_ref
#: (Section II.B).
METERS = {
    "hvac": ("heater", "compressor", "fans"),
    "hvac_and_floor": ("heater", "floor_wall", "compressor", "fans"),
}
#: The meter of every headline saving: the paper's.
HEADLINE_METER = "hvac"
#: How reports and the dashboard name each meter.
METER_LABELS = {"hvac": "HVAC units", "hvac_and_floor": "HVAC + floor/wall heating"}
