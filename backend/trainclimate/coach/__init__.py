"""The coach as the layers above see it: its vocabulary.

Modules: ``rule`` (the rule-based controller's T_rule curve and the HVAC modes), ``setpoint`` (the
band a reference may move in, the comfort band, and how a reference is applied), ``states`` (the
HVAC states' codes and names) and ``meters`` (what each electrical meter counts). The simulator
(:mod:`trainclimate.sim`), the twin, the controller, the analyses and the service all speak it; it
imports nothing else of the package.
"""
