"""Whether a coach's decks are within the comfort band now: its newest telemetry row against
T_rule ± T_max (the bound the controller holds the decks to,
:data:`trainclimate.coach.setpoint.COMFORT_BAND_K`).

This is the instantaneous check the coaches list shows beside each coach's status. The fleet
summary's attention list keeps its own rule over time (a coach outside the band for more than
30 minutes without a break, :func:`.fleet_summary.comfort_violations`); both judge a deck the
same way: outside when |T_room − T_rule| − T_max > 0, in regular mode only (the band does not
apply in slumber or off), a deck without a reading counting as within.
"""

from __future__ import annotations

from collections.abc import Sequence

from trainclimate.service.store.records import ComfortNow

#: The decks, in the order of a view's ``t_room_c``.
DECK_NAMES = ("up", "mid", "low")


def comfort_now(
    t_room_c: Sequence[float | None] | None,
    t_rule_c: float | None,
    mode: str | None,
    band_k: float,
) -> ComfortNow | None:
    """The comfort of a coach's newest telemetry row.

    Parameters
    ----------
    t_room_c : sequence of float or None, or None
        The row's deck temperatures up, mid, low (None: no row; an element None: no reading of
        that deck). [°C]
    t_rule_c : float or None
        The row's rule-based setpoint T_rule, the band's centre. [°C]
    mode : str or None
        The row's HVAC mode; the band applies in ``"regular"`` mode only.
    band_k : float
        The band's half-width T_max. [K]

    Returns
    -------
    ComfortNow or None
        ``in_band`` (bool: every deck with a reading within T_rule ± ``band_k``),
        ``worst_excess_k`` (how far the worst deck lies outside the band, 0 when all are
        within, K) and ``decks_out`` (the names of the decks outside, of :data:`DECK_NAMES`);
        None when it is unknown: no row, no T_rule, not in regular mode, or no deck reading.
    """
    if t_room_c is None or t_rule_c is None or mode != "regular":
        return None
    excess = {
        deck: abs(t - t_rule_c) - band_k
        for deck, t in zip(DECK_NAMES, t_room_c, strict=True)
        if t is not None
    }
    if not excess:
        return None
    out = [deck for deck, e in excess.items() if e > 0]
    return {
        "in_band": not out,
        "worst_excess_k": max(0.0, *excess.values()),
        "decks_out": out,
    }
