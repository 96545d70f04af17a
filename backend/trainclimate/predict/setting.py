"""The controller's setting of the predictor (the paper's, Sections IV.A and V).

5-min samples, a 60-min lead-in (ρ = 12 samples) and a 30-min horizon (T = 6 steps): the setting
of the default model, the DDPC controller and the service's loop.
"""

#: Sampling time. [min]
SAMPLING_MIN = 5
#: Lead-in ρ: past samples the prediction starts from.
RHO = 12
#: Horizon T: prediction steps.
HORIZON = 6
