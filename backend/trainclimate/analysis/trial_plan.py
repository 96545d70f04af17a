"""A trial's calendar and plans: service days, and which coach of a pair runs the layer on which
day (:mod:`trainclimate.analysis.trial` estimates the savings from them).

**Plans** (:data:`PLANS`). A *service day* runs from the switch hour (local time, Europe/Zurich,
default 03:00, when the trains stand in the depot) to the next day's. Coach 0 and coach 1 are the
train's two coaches in a fixed order (the service orders them by id).

- ``fixed``: one coach always activated (the operator's choice).
- ``alternate``: coach 0 on even day numbers (proleptic Gregorian ordinal), coach 1 on odd ones.
- ``randomized``: in blocks of two consecutive days (ordinals 2k, 2k + 1), each coach gets one
  day, the order drawn from the seed and the block (balanced, reproducible).
- ``reference``: neither coach activated: both on T_rule, which measures the coaches' own ratio.
"""

from __future__ import annotations

from datetime import date

import numpy as np
import pandas as pd

#: The trial plans a train can run.
PLANS = ("fixed", "alternate", "randomized", "reference")
#: Local hour at which a service day starts (the trains stand in the depot). [h]
DEFAULT_SWITCH_HOUR = 3
#: Where service days are counted.
LOCAL_TZ = "Europe/Zurich"
#: Neither coach activated (a ``reference`` day), in the ``activated`` arrays.
NEITHER = -1
#: ``date(1970, 1, 1).toordinal()``.
_ORDINAL_1970 = 719163


def service_day(time: pd.Timestamp, switch_hour: int = DEFAULT_SWITCH_HOUR) -> date:
    """The service day ``time`` belongs to: the local (Europe/Zurich) date of ``time`` less
    ``switch_hour`` hours.

    Parameters
    ----------
    time : pandas.Timestamp
        Timezone-aware.
    switch_hour : int, default 3
        Local hour at which a service day starts, 0–23. [h]

    Returns
    -------
    datetime.date
    """
    local = pd.Timestamp(time).tz_convert(LOCAL_TZ)
    return (local - pd.Timedelta(hours=switch_hour)).date()


def service_days(times: pd.DatetimeIndex, switch_hour: int = DEFAULT_SWITCH_HOUR) -> np.ndarray:
    """:func:`service_day` of every time, as day ordinals (``date.toordinal()``), shape (n,)."""
    local = pd.DatetimeIndex(times).tz_convert(LOCAL_TZ) - pd.Timedelta(hours=switch_hour)
    days = local.tz_localize(None).normalize().to_numpy().astype("datetime64[D]")
    return days.astype(np.int64) + _ORDINAL_1970


def day_start(day: date, switch_hour: int = DEFAULT_SWITCH_HOUR) -> pd.Timestamp:
    """When service day ``day`` starts: ``switch_hour`` local time on that date, in UTC (on a
    daylight-saving change the hour as the local clock reads it)."""
    local = pd.Timestamp(year=day.year, month=day.month, day=day.day, hour=switch_hour).tz_localize(
        LOCAL_TZ, nonexistent="shift_forward", ambiguous=False
    )
    return local.tz_convert("UTC")


def activated(plan: str, day: date | int, seed: int = 0, fixed: int = 0) -> int:
    """Which coach of the pair runs the layer on service day ``day`` under ``plan``.

    Parameters
    ----------
    plan : str
        One of :data:`PLANS`.
    day : datetime.date or int
        The service day, or its ordinal (a Python or numpy integer, as :func:`service_days`
        gives).
    seed : int, default 0
        The ``randomized`` plan's seed.
    fixed : int, default 0
        The ``fixed`` plan's activated coach.

    Returns
    -------
    int
        0 or 1, or :data:`NEITHER` on a ``reference`` day.

    Raises
    ------
    ValueError
        For an unknown plan or a coach other than 0 or 1.
    """
    n = day.toordinal() if isinstance(day, date) else int(day)
    if plan == "fixed":
        if fixed not in (0, 1):
            raise ValueError("the fixed plan's coach is 0 or 1")
        return fixed
    if plan == "alternate":
        return n % 2
    if plan == "randomized":
        first = int(np.random.default_rng([int(seed), n // 2]).integers(2))
        return first if n % 2 == 0 else 1 - first
    if plan == "reference":
        return NEITHER
    raise ValueError(f"unknown plan {plan!r}: expected one of {', '.join(PLANS)}")
