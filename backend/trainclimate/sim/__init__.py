"""The half-coach thermal simulator of the paper's Section II (see docs/model.md).

Modules: ``rule`` (rule-based controller and HVAC modes), ``hvac`` (state machine, substate, PID,
floor/wall heating), ``thermal`` (heat distribution and the nine-state coach block), ``power``
(electrical power), ``solar``, ``weather`` and ``routes`` (inputs), ``params`` (coach parameters
and diversity; their plausible ranges in ``plausible``), ``scenarios`` (named, seeded settings) and
``simulator`` (the vectorised fleet). It imports nothing else of the package; the twin calibrated
to a real coach's logs is :mod:`trainclimate.twin`.
"""
