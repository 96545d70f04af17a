"""The coaches that need an operator's attention, and the coaches by status, from the views the
fleet list shows (:mod:`.queries`) and how long each coach has been outside the comfort band
(:func:`.fleet_summary.comfort_violations`)."""

from __future__ import annotations

from collections import Counter

from trainclimate.service.store.records import CoachView

#: A coach whose decks have been outside the comfort band this long, without a break, needs
#: attention. [min]
VIOLATION_ATTENTION_MIN = 30.0
#: How far back a coach's comfort is read for the attention list. [min]
VIOLATION_LOOKBACK_MIN = 120.0
#: The concerns of the attention list, in its order.
KINDS = ("costing_energy", "stale", "disconnected", "fallback", "override", "comfort")
#: The setpoint reason of a coach whose train's guard handed the layer back to T_rule (listed as
#: ``costing_energy``, with the figures, not as a fallback).
GUARD_REASON = "costing_energy"


def attention(
    views: list[CoachView], violating_min: dict[str, float], guards: dict[str, dict] | None = None
) -> list[dict]:
    """The coaches that need an operator's attention, from their views (as the fleet list shows
    them), the trains whose guard handed the layer back to T_rule and the minutes each coach has
    been outside the comfort band (:func:`.fleet_summary.comfort_violations`): costing energy
    (the train's guard tripped: one entry per train, on the coach the layer was on, with the
    figures), stale (no telemetry), disconnected (its newest
    telemetry says the link to the HVAC is down: the HVAC holds T_rule, not the T_ref issued),
    in fallback (with the reason), overridden, or outside the band for longer than
    :data:`VIOLATION_ATTENTION_MIN`.

    Parameters
    ----------
    views : list of CoachView
        The coaches' views (:func:`.queries.coach_view` with :func:`.queries.with_liveness`).
    violating_min : dict
        Coach id → how long its decks have been outside the comfort band without a break. [min]
    guards : dict, optional
        Train id → ``coach_id`` (the coach the layer was on when the guard tripped) and
        ``figures`` (:func:`trainclimate.analysis.guard.figures`), for the trains whose guard
        has tripped.

    Returns
    -------
    list of dict
        One entry per coach and concern: ``coach_id``, ``train_id``, ``kind`` (one of
        :data:`KINDS`), ``status``, ``reason`` (the view's reason code: the setpoint's, or
        ``connection_lost``; or None), ``detail`` in words and ``figures`` (``costing_energy``:
        the guard's; else None); in the order of :data:`KINDS`, then by coach.
    """
    out = []
    by_coach = {v["id"]: v for v in views}
    for train_id, g in sorted((guards or {}).items()):
        v = by_coach.get(g["coach_id"]) or next(
            (v for v in views if v["train_id"] == train_id), None
        )
        if v is None:
            continue
        f = g["figures"] or {}
        ci = f.get("savings_ci95_pct") or [float("nan")] * 2
        detail = (
            f"the layer cost this pair energy: {f.get('savings_pct', float('nan')):.1f} % "
            f"(95 % CI {ci[0]:.1f} to {ci[1]:.1f}) over {f.get('days', 0)} service days; "
            "handed back to T_rule until an operator re-enables it"
        )
        out.append(
            {"coach_id": v["id"], "train_id": train_id, "kind": GUARD_REASON,
             "status": v["status"], "reason": GUARD_REASON, "detail": detail, "figures": f}
        )  # fmt: skip
    for v in views:
        base = {
            "coach_id": v["id"],
            "train_id": v["train_id"],
            "status": v["status"],
            "reason": v["reason"],
            "figures": None,
        }
        if v["status"] == "fallback" and v["reason"] == GUARD_REASON:
            pass  # listed with its train's guard above
        elif v["status"] == "stale":
            out.append({**base, "kind": "stale", "detail": "no telemetry in time"})
        elif v["status"] == "disconnected":
            out.append({**base, "kind": "disconnected", "detail": _disconnected(v)})
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
    return sorted(out, key=lambda e: (KINDS.index(e["kind"]), e["coach_id"]))


def _disconnected(view: CoachView) -> str:
    """What a ``disconnected`` coach's HVAC does, in words, from its view."""
    t_rule = view.get("t_rule_c")
    holds = f"T_rule {t_rule:.1f} °C" if t_rule is not None else "its T_rule"
    return f"link to the HVAC lost: it holds {holds}, not the T_ref issued"


def coaches_by_status(views: list[CoachView]) -> dict[str, int]:
    """Status → how many coaches have it (as the fleet list shows them)."""
    return dict(sorted(Counter(v["status"] for v in views).items()))
