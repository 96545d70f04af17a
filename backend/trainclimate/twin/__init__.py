"""A calibrated twin of one real coach: the simulator fitted to the coach's logged trajectories
(docs/model.md, "Calibration: a twin of one real coach").

It sits above :mod:`trainclimate.sim` (the simulator it calibrates) and :mod:`trainclimate.data`
(the trajectories it is fitted to) and below the commands and the service that use a twin; the
simulator imports nothing of it.

Modules: ``knobs`` (the calibrated quantities and how they change a coach's parameters),
``replay`` (the logged trajectories run through the simulator, and the residuals the fit scores),
``fit`` (the least-squares problem and its Jacobian's standard errors and correlations),
``bootstrap`` (95 % intervals from re-fits on training days resampled whole), ``validation``
(the held-out days, the twin's errors on them per ambient band, the range they validate),
``response`` (the setpoint changes in the logged T_ref, and the twin's energy response to them),
``calibration`` (``calibrate``: one coach's twin, from the above) and ``validity`` (the twin's
coach-params file with the calibration's record, and the warning of weather outside its
validated range).
"""
