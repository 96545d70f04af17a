"""A fleet study's answer: energy, savings, comfort cost, money and CO₂, in total, per month, per
situation and per coach.

Savings are 1 − E_ddpc / E_rule on the headline meter, the HVAC units (heater, compressor, fans:
what the paper's loggers metered), with the whole coach's (with floor and wall heating) beside
it. The average hourly violation is the discomfort (K·h, mean of the decks) divided by the
regular-mode hours counted, the paper's Table II measure. Money and CO₂ are the saved energy
times a price and an emission factor given with the study (defaults below).

The savings in total, per month and per situation carry a 95 % confidence interval from the
two-way bootstrap over coaches and days (:mod:`trainclimate.study.bootstrap`), seeded from the
study's seed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from trainclimate.coach.meters import HEADLINE_METER
from trainclimate.sim.seeding import seed_of
from trainclimate.study.bootstrap import CONFIDENCE, RESAMPLES, coach_day_table, savings_interval
from trainclimate.study.chunk import OTHER_METER, SITUATIONS
from trainclimate.study.plan import StudySpec

#: Default electricity price: an assumption of the order of the Swiss tariffs for large
#: consumers published by ElCom (20 Rp./kWh); give your own with ``--price-chf-kwh``. [CHF/kWh]
PRICE_CHF_PER_KWH = 0.20
#: Default emission factor: the Swiss consumer mix, life cycle, after KBOB Ökobilanzdaten im
#: Baubereich 2009/1:2022 (125 g CO₂-eq/kWh); SBB's own railway electricity (mostly hydro) is
#: far lower — give it with ``--co2-kg-kwh``. [kg CO₂-eq/kWh]
CO2_KG_PER_KWH = 0.125


def _pct(saved: float, base: float) -> float | None:
    return float(100.0 * saved / base) if base > 0 else None


def _group(frame: pd.DataFrame, controllers: tuple[str, ...]) -> dict:
    """Energy, savings and violation of a set of rows."""
    regular_h = float(frame["regular_hours"].sum())
    out: dict = {}
    for kind in controllers:
        out[f"energy_{kind}_kwh"] = float(frame[f"energy_{kind}_kwh"].sum())
    rule = out["energy_rule_kwh"]
    out["savings_pct"] = _pct(rule - out["energy_ddpc_kwh"], rule)
    if "edge" in controllers:
        out["edge_savings_pct"] = _pct(rule - out["energy_edge_kwh"], rule)
    whole_rule = float(frame["energy_whole_rule_kwh"].sum())
    whole_ddpc = float(frame["energy_whole_ddpc_kwh"].sum())
    out["savings_by_meter_pct"] = {
        HEADLINE_METER: out["savings_pct"],
        OTHER_METER: _pct(whole_rule - whole_ddpc, whole_rule),
    }
    for kind in controllers:
        key = "avg_hourly_violation_k" if kind == "ddpc" else f"avg_hourly_violation_{kind}_k"
        out[key] = float(frame[f"discomfort_{kind}_kh"].sum() / regular_h) if regular_h else 0.0
    out["hours"] = float(frame["hours"].sum())
    out["regular_hours"] = regular_h
    return out


def _intervals(
    frame: pd.DataFrame,
    controllers: tuple[str, ...],
    coaches: pd.Index,
    days: pd.Index,
    seed: int,
) -> dict:
    """The savings' confidence intervals of a set of rows over ``coaches`` × ``days``:
    ``savings_ci95_pct`` (and ``edge_savings_ci95_pct``), each ``[low, high]`` in % or None,
    with ``…_reason`` saying why (None when there is an interval)."""
    base = coach_day_table(frame, "energy_rule_kwh", coaches, days)
    out: dict = {}
    for kind, key in (("ddpc", "savings"), ("edge", "edge_savings")):
        if kind in controllers:
            other = coach_day_table(frame, f"energy_{kind}_kwh", coaches, days)
            ci = savings_interval(base, other, seed=seed)
            out[f"{key}_ci95_pct"] = ci.pct
            out[f"{key}_ci95_reason"] = ci.reason
    return out


def savings_text(pct: float | None, ci: list[float] | None, reason: str | None = None) -> str:
    """A saving with its interval, e.g. ``6.2 % (95 % CI 5.9 to 6.5)``.

    Parameters
    ----------
    pct : float or None
        The saving. [%]
    ci : list of float or None
        Its interval ``[low, high]``. [%]
    reason : str, optional
        Why there is no interval.

    Returns
    -------
    str
        ``–`` without a saving; the saving alone, or with the reason, without an interval.
    """
    if pct is None:
        return "–"
    if ci is None:
        return f"{pct:.1f} %" + (f" (no 95 % CI: {reason})" if reason else "")
    return f"{pct:.1f} % (95 % CI {ci[0]:.1f} to {ci[1]:.1f})"


def summarise(
    frame: pd.DataFrame,
    spec: StudySpec,
    *,
    price_chf_per_kwh: float = PRICE_CHF_PER_KWH,
    co2_kg_per_kwh: float = CO2_KG_PER_KWH,
) -> dict:
    """The study's answer from its rows (:func:`~trainclimate.study.runner.read_chunks`).

    Parameters
    ----------
    frame : pandas.DataFrame
        Every chunk's rows.
    spec : StudySpec
        The study.
    price_chf_per_kwh : float
        Electricity price. [CHF/kWh]
    co2_kg_per_kwh : float
        Emission factor. [kg CO₂-eq/kWh]

    Returns
    -------
    dict
        ``coach_days``, ``meter``, ``energy_<controller>_kwh``, ``savings_pct`` (and
        ``edge_savings_pct``), ``savings_by_meter_pct``, ``energy_by_meter_kwh``,
        ``avg_hourly_violation_k`` (the layer's; the baseline's as
        ``avg_hourly_violation_rule_k``), ``saved_mwh``, ``saved_chf``, ``saved_t_co2``,
        ``price_chf_per_kwh``, ``co2_kg_per_kwh``, ``by_month``, ``by_situation`` (each row
        the same measures), ``by_coach`` (each coach's savings and violation) and
        ``coach_savings_pct`` (their spread: min, p5, median, p95, max). The total, each month
        and each situation carry ``savings_ci95_pct`` (and ``edge_savings_ci95_pct``):
        ``[low, high]`` in %, the 95 % interval of the two-way bootstrap over the study's
        coaches and the days (the month's, in a month), or None with ``savings_ci95_reason``
        (fewer than 2 coaches or 2 days, or no baseline energy in over 1 % of the resamples);
        ``bootstrap`` says how (design, method, resamples, confidence, seed — the study's
        seed's own stream).
    """
    ctl = spec.controllers
    coaches = pd.Index(np.sort(frame["coach_index"].unique()))
    days = pd.Index(np.sort(frame["day"].unique()))
    seed = seed_of(spec.seed, 4)
    total = {**_group(frame, ctl), **_intervals(frame, ctl, coaches, days, seed)}
    saved_kwh = total["energy_rule_kwh"] - total["energy_ddpc_kwh"]
    out = {
        "coach_days": int(frame.groupby(["coach_index", "day"]).ngroups),
        "coaches": spec.n_coaches,
        "days": spec.days,
        "meter": HEADLINE_METER,
        **total,
        "energy_by_meter_kwh": {
            HEADLINE_METER: {k: total[f"energy_{k}_kwh"] for k in ctl},
            OTHER_METER: {k: float(frame[f"energy_whole_{k}_kwh"].sum()) for k in ctl},
        },
        "saved_mwh": saved_kwh / 1e3,
        "saved_chf": saved_kwh * price_chf_per_kwh,
        "saved_t_co2": saved_kwh * co2_kg_per_kwh / 1e3,
        "price_chf_per_kwh": price_chf_per_kwh,
        "co2_kg_per_kwh": co2_kg_per_kwh,
        "bootstrap": {
            "design": "coaches and days resampled independently with replacement (two-way)",
            "method": "percentile",
            "resamples": RESAMPLES,
            "confidence": CONFIDENCE,
            "seed": seed,
        },
    }
    month = frame["day"].str[:7]
    out["by_month"] = [
        {
            "month": m,
            "coach_days": int(g.groupby(["coach_index", "day"]).ngroups),
            **_group(g, ctl),
            **_intervals(g, ctl, coaches, days[days.str[:7] == m], seed),
        }
        for m, g in frame.groupby(month, sort=True)
    ]
    out["by_situation"] = []
    for s in SITUATIONS:
        rows = frame[frame["situation"] == s]
        if len(rows):
            out["by_situation"].append(
                {"situation": s, **_group(rows, ctl), **_intervals(rows, ctl, coaches, days, seed)}
            )
    coaches = [
        {"coach": g["coach"].iloc[0], **_group(g, ctl)}
        for _, g in frame.groupby("coach_index", sort=True)
    ]
    out["by_coach"] = [
        {
            "coach": c["coach"],
            "energy_rule_kwh": c["energy_rule_kwh"],
            "energy_ddpc_kwh": c["energy_ddpc_kwh"],
            "savings_pct": c["savings_pct"],
            "avg_hourly_violation_k": c["avg_hourly_violation_k"],
        }
        for c in coaches
    ]
    pct = np.array([c["savings_pct"] for c in coaches if c["savings_pct"] is not None])
    out["coach_savings_pct"] = (
        dict(
            zip(
                ("min", "p5", "median", "p95", "max"),
                (float(v) for v in np.percentile(pct, [0, 5, 50, 95, 100])),
                strict=True,
            )
        )
        if len(pct)
        else None
    )
    return out


def by_coach_day(frame: pd.DataFrame) -> pd.DataFrame:
    """One row per coach-day: its mean outside temperature, energy under rule and DDPC (kWh) and
    the layer's saving (%)."""
    days = frame.groupby(["coach_index", "day"], sort=True).agg(
        t_amb_mean_c=("t_amb_mean_c", "first"),
        energy_rule_kwh=("energy_rule_kwh", "sum"),
        energy_ddpc_kwh=("energy_ddpc_kwh", "sum"),
    )
    rule = days["energy_rule_kwh"]
    days["savings_pct"] = np.where(
        rule > 0, 100.0 * (rule - days["energy_ddpc_kwh"]) / rule.where(rule > 0, 1.0), np.nan
    )
    return days.reset_index()
