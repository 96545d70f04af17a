"""The half-coach thermal simulator of the paper's Section II (see docs/model.md).

Modules: ``hvac`` (state machine, substate, PID, floor/wall heating), ``thermal`` (heat
distribution and the nine-state coach block), ``power`` (electrical power), ``solar``, ``weather``
and ``routes`` (inputs), ``params`` (coach parameters and diversity; their plausible ranges in
``plausible``), ``scenarios`` (named, seeded settings) and ``simulator`` (the vectorised fleet).
The coach's vocabulary it speaks — the rule-based controller and the HVAC modes, the setpoint
band, the HVAC states, the meters — is :mod:`trainclimate.coach`, the only other part of the
package it imports; the twin calibrated to a real coach's logs is :mod:`trainclimate.twin`.
"""
