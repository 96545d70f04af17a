"""The HVAC states (paper, Section II.B): their codes and names.

Regular mode: preheating, precooling, heating, cooling, mixed. Slumber mode: active heating,
active ventilation, active cooling, off. Off mode: off. The state machine that moves between them
is the simulator's (:func:`trainclimate.sim.hvac.next_state`); the codes are what a simulated run
records and what the analyses count.
"""

from __future__ import annotations

#: The states' codes (a run records them as int8).
OFF = 0
PREHEATING, PRECOOLING, HEATING, COOLING, MIXED = 1, 2, 3, 4, 5
SLUMBER_HEATING, SLUMBER_VENTILATION, SLUMBER_COOLING, SLUMBER_OFF = 6, 7, 8, 9
#: How reports and the experiments name each state.
STATE_NAMES = {
    OFF: "off",
    PREHEATING: "preheating",
    PRECOOLING: "precooling",
    HEATING: "heating",
    COOLING: "cooling",
    MIXED: "mixed",
    SLUMBER_HEATING: "slumber_heating",
    SLUMBER_VENTILATION: "slumber_ventilation",
    SLUMBER_COOLING: "slumber_cooling",
    SLUMBER_OFF: "slumber_off",
}
#: The states of regular and of slumber mode (off mode has only ``OFF``).
REGULAR_STATES = (PREHEATING, PRECOOLING, HEATING, COOLING, MIXED)
SLUMBER_STATES = (SLUMBER_HEATING, SLUMBER_VENTILATION, SLUMBER_COOLING, SLUMBER_OFF)
