"""The coaches that need an operator's attention, and the coaches by status, from the views the
fleet list shows (:mod:`.queries`) and how long each coach has been outside the comfort band
(:func:`.fleet_summary.comfort_violations`)."""

from __future__ import annotations

from collections import Counter

#: A coach whose decks have been outside the comfort band this long, without a break, needs
#: attention. [min]
VIOLATION_ATTENTION_MIN = 30.0
#: How far back a coach's comfort is read for the attention list. [min]
VIOLATION_LOOKBACK_MIN = 120.0


def attention(views: list[dict], violating_min: dict[str, float]) -> list[dict]:
    """The coaches that need an operator's attention, from their views (as the fleet list shows
    them) and the minutes each has been outside the comfort band
    (:func:`.fleet_summary.comfort_violations`): stale (no telemetry), in fallback (with the
    reason), overridden, or outside the band for longer than :data:`VIOLATION_ATTENTION_MIN`.

    Returns
    -------
    list of dict
        One entry per coach and concern: ``coach_id``, ``train_id``, ``kind`` (``stale``,
        ``fallback``, ``override``, ``comfort``), ``status``, ``reason`` (the setpoint's reason
        code, or None) and ``detail`` in words; stale first, then fallback, override, comfort.
    """
    out = []
    for v in views:
        base = {
            "coach_id": v["id"],
            "train_id": v["train_id"],
            "status": v["status"],
            "reason": v["reason"],
        }
        if v["status"] == "stale":
            out.append({**base, "kind": "stale", "detail": "no telemetry in time"})
        elif v["status"] == "fallback":
            out.append(
                {**base, "kind": "fallback", "detail": f"rule-based setpoint: {v['reason']}"}
            )
        elif v["status"] == "override":
            # the newest tick issued an override's T_ref; it may have been cancelled since
            until = v["override_until"]
            when = f" until {until:%Y-%m-%d %H:%M} UTC" if until is not None else ""
            out.append({**base, "kind": "override", "detail": f"operator's setpoint{when}"})
        minutes = violating_min.get(v["id"], 0.0)
        if minutes > VIOLATION_ATTENTION_MIN:
            more = "more than " if minutes >= VIOLATION_LOOKBACK_MIN else ""
            out.append(
                {
                    **base,
                    "kind": "comfort",
                    "detail": f"outside the comfort band for {more}{minutes:.0f} min",
                }
            )
    order = {"stale": 0, "fallback": 1, "override": 2, "comfort": 3}
    return sorted(out, key=lambda e: (order[e["kind"]], e["coach_id"]))


def coaches_by_status(views: list[dict]) -> dict[str, int]:
    """Status → how many coaches have it (as the fleet list shows them)."""
    return dict(sorted(Counter(v["status"] for v in views).items()))
