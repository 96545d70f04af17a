"""The HVAC interface as the predictive layer sees it: the band and how a reference is applied.

The layer may move the setpoint only within the band the driver could set by hand,
T_rule ± :data:`U_BAND_K` (the paper's constraint (6)); operators' overrides are held to the same
band. The comfort band the decks are held to is the narrower T_rule ± :data:`COMFORT_BAND_K`
(the paper's T_max, Eq. (4)): the controller's bound, and what every violation figure measures.
Whatever sends a reference — the closed-loop simulation, the demo fleet, an onboard gateway —
applies it the same way (:func:`apply_setpoint`).
"""

from __future__ import annotations

import numpy as np

#: Half-width of the band around T_rule the reference must stay in. [K]
U_BAND_K = 2.0
#: Half-width T_max of the comfort band around T_rule (paper, Eq. (4)). [K]
COMFORT_BAND_K = 1.0


def apply_setpoint(t_ref, t_rule, use) -> np.ndarray:
    """The reference the HVAC's tracking controller follows.

    Parameters
    ----------
    t_ref : array_like
        The layer's reference T_ref (NaN: none). [°C]
    t_rule : array_like
        The rule-based setpoint T_rule. [°C]
    use : array_like of bool
        Where T_ref may be applied at all: regular mode, and whatever else the caller requires
        (a valid, unexpired setpoint; the layer active; the link up).

    Returns
    -------
    numpy.ndarray
        T_ref clipped to T_rule ± :data:`U_BAND_K` where ``use`` and T_ref is finite, else T_rule.
        [°C]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Eq. (6).
    """
    t_ref = np.asarray(t_ref, dtype=float)
    t_rule = np.asarray(t_rule, dtype=float)
    applied = np.asarray(use, dtype=bool) & np.isfinite(t_ref)
    return np.where(applied, np.clip(t_ref, t_rule - U_BAND_K, t_rule + U_BAND_K), t_rule)
