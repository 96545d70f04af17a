"""The rule-based controller (paper, Section II.A): T_rule from T_amb, and the HVAC modes.

The paper states only that the rules yield "a non-decreasing piecewise linear relation between the
reference temperature and the ambient temperature". SBB's curve is not published; the default
here is an ASSUMPTION (22 °C up to 19 °C outside, then +0.25 K per K, held above 35 °C) and every
caller can pass its own :class:`RuleCurve`. The simulator runs the curve and the modes
(:mod:`trainclimate.sim`); the data, the controller, the analyses and the service read them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: HVAC modes (paper, Section II.A).
MODE_OFF, MODE_SLUMBER, MODE_REGULAR = 0, 1, 2
MODE_NAMES = {MODE_OFF: "off", MODE_SLUMBER: "slumber", MODE_REGULAR: "regular"}

#: Which mode each train operation selects: in service → regular, a layover → slumber, parked
#: overnight → off.
MODE_OF_OPERATION = {"service": MODE_REGULAR, "layover": MODE_SLUMBER, "parked": MODE_OFF}


@dataclass(frozen=True)
class RuleCurve:
    """The rule-based controller: a non-decreasing piecewise-linear T_rule(T_amb).

    The curve is held constant outside its breakpoints. Calling it maps ambient temperatures to
    rule-based setpoints, ``RuleCurve()(t_amb_c)``.

    Attributes
    ----------
    t_amb_c : tuple of float
        Ambient-temperature breakpoints, strictly increasing, at least 2. [°C]
    t_rule_c : tuple of float
        T_rule at each breakpoint, non-decreasing, same length as ``t_amb_c``. [°C]
    assumption : str
        Note on where the curve comes from (ignored in comparisons).

    Raises
    ------
    ValueError
        On construction, if the breakpoints are fewer than 2, of unequal length, not strictly
        increasing in T_amb, or T_rule decreases.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section II.A.
    """

    t_amb_c: tuple[float, ...] = (19.0, 35.0)
    t_rule_c: tuple[float, ...] = (22.0, 26.0)
    assumption: str = field(
        default="default curve is an assumption: 22 °C up to 19 °C outside, +0.25 K/K above, "
        "held at 26 °C above 35 °C",
        compare=False,
    )

    def __post_init__(self) -> None:
        x = np.asarray(self.t_amb_c, dtype=float)
        y = np.asarray(self.t_rule_c, dtype=float)
        if x.ndim != 1 or x.shape != y.shape or x.size < 2:
            raise ValueError("rule curve needs ≥ 2 breakpoints with matching T_amb and T_rule")
        if np.any(np.diff(x) <= 0):
            raise ValueError("rule curve T_amb breakpoints must be strictly increasing")
        if np.any(np.diff(y) < 0):
            raise ValueError("rule curve T_rule must be non-decreasing in T_amb")

    def __call__(self, t_amb_c: np.ndarray | float) -> np.ndarray:
        """Evaluate the curve.

        Parameters
        ----------
        t_amb_c : array-like or float
            Ambient temperature, any shape. [°C]

        Returns
        -------
        numpy.ndarray
            T_rule, same shape as ``t_amb_c``. [°C]
        """
        return np.interp(t_amb_c, self.t_amb_c, self.t_rule_c)


def mode_from_operation(operation: np.ndarray) -> np.ndarray:
    """HVAC mode codes for an array of train operation labels.

    In service → regular, a layover → slumber, parked overnight → off (:data:`MODE_OF_OPERATION`).

    Parameters
    ----------
    operation : array-like of str
        Labels ``"service"``, ``"layover"`` or ``"parked"``, any shape.

    Returns
    -------
    numpy.ndarray of int8
        ``MODE_REGULAR``, ``MODE_SLUMBER`` or ``MODE_OFF``, same shape as ``operation``.

    Raises
    ------
    ValueError
        For an unknown label (all unknown labels are named).
    """
    operation = np.asarray(operation)
    out = np.full(operation.shape, -1, dtype=np.int8)
    for label, mode in MODE_OF_OPERATION.items():
        out[operation == label] = mode
    if np.any(out < 0):
        unknown = sorted(set(operation[out < 0].tolist()))
        raise ValueError(f"unknown train operation(s): {unknown}")
    return out
