"""A fleet study's HTML report: monthly savings with their 95 % intervals, savings against the
outside temperature, the spread over coaches and the comfort cost, as Plotly charts in one
self-contained page."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from trainclimate.analysis.report import fmt_num, html_page
from trainclimate.study.summary import by_coach_day, savings_text


def _monthly(summary: dict) -> go.Figure:
    months = [m["month"] for m in summary["by_month"]]
    fig = go.Figure()
    fig.add_bar(x=months, y=[m["energy_rule_kwh"] / 1e3 for m in summary["by_month"]],
                name="rule-based (MWh)")  # fmt: skip
    fig.add_bar(x=months, y=[m["energy_ddpc_kwh"] / 1e3 for m in summary["by_month"]],
                name="DDPC layer (MWh)")  # fmt: skip
    rows = summary["by_month"]
    # no interval → no bar (the saving is None too when the month used no energy)
    above = [None if m["savings_ci95_pct"] is None else m["savings_ci95_pct"][1] - m["savings_pct"]
             for m in rows]  # fmt: skip
    below = [None if m["savings_ci95_pct"] is None else m["savings_pct"] - m["savings_ci95_pct"][0]
             for m in rows]  # fmt: skip
    fig.add_scatter(x=months, y=[m["savings_pct"] for m in rows], name="savings (%), 95 % CI",
                    yaxis="y2", mode="lines+markers",
                    error_y={"type": "data", "symmetric": False, "array": above,
                             "arrayminus": below})  # fmt: skip
    fig.update_layout(
        title=f"Energy per month ({summary['meter']} meter) and the layer's saving",
        yaxis={"title": "MWh"},
        yaxis2={"title": "savings (%)", "overlaying": "y", "side": "right"},
        barmode="group",
    )
    return fig


def _vs_temperature(frame: pd.DataFrame) -> go.Figure:
    days = by_coach_day(frame)
    bins = np.floor(days["t_amb_mean_c"] / 2.0) * 2.0
    grouped = days.groupby(bins).agg(
        rule=("energy_rule_kwh", "sum"), ddpc=("energy_ddpc_kwh", "sum")
    )
    pct = 100.0 * (grouped["rule"] - grouped["ddpc"]) / grouped["rule"].where(grouped["rule"] > 0)
    fig = go.Figure()
    fig.add_scatter(x=days["t_amb_mean_c"], y=days["savings_pct"], mode="markers",
                    name="coach-days", marker={"size": 4, "opacity": 0.4})  # fmt: skip
    fig.add_scatter(x=grouped.index + 1.0, y=pct, mode="lines+markers",
                    name="energy-weighted, 2 K bins")  # fmt: skip
    fig.update_layout(
        title="Savings against the day's mean outside temperature",
        xaxis={"title": "mean outside temperature (°C)"},
        yaxis={"title": "savings (%)"},
    )
    return fig


def _coaches(summary: dict) -> go.Figure:
    pct = [c["savings_pct"] for c in summary["by_coach"] if c["savings_pct"] is not None]
    fig = go.Figure(go.Histogram(x=pct, nbinsx=30, name="coaches"))
    fig.update_layout(
        title="Savings over the study, coach by coach",
        xaxis={"title": "savings (%)"},
        yaxis={"title": "coaches"},
    )
    return fig


def _comfort(summary: dict) -> go.Figure:
    months = [m["month"] for m in summary["by_month"]]
    fig = go.Figure()
    fig.add_scatter(x=months, y=[m["avg_hourly_violation_rule_k"] for m in summary["by_month"]],
                    name="rule-based", mode="lines+markers")  # fmt: skip
    fig.add_scatter(x=months, y=[m["avg_hourly_violation_k"] for m in summary["by_month"]],
                    name="DDPC layer", mode="lines+markers")  # fmt: skip
    fig.update_layout(
        title="Comfort cost: average hourly violation of T_rule ± 1 K",
        yaxis={"title": "K"},
    )
    return fig


def write_study_report(summary: dict, frame: pd.DataFrame, path: str | Path) -> Path:
    """Write the study's report.

    Parameters
    ----------
    summary : dict
        :func:`~trainclimate.study.summary.summarise`'s answer.
    frame : pandas.DataFrame
        The study's rows.
    path : str or pathlib.Path
        The HTML file.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    s = summary
    rows = "".join(
        f"<tr><td>{html.escape(r['situation'])}</td><td>{fmt_num(r['hours'] / 1e3, '.1f')}</td>"
        f"<td>{fmt_num(r['energy_rule_kwh'] / 1e3, '.1f')}</td>"
        f"<td>{fmt_num(r['energy_ddpc_kwh'] / 1e3, '.1f')}</td>"
        f"<td>{html.escape(savings_text(r['savings_pct'], r['savings_ci95_pct']))}</td>"
        f"<td>{fmt_num(r['avg_hourly_violation_k'], '.4f')}</td></tr>"
        for r in s["by_situation"]
    )
    saving = savings_text(s["savings_pct"], s["savings_ci95_pct"], s["savings_ci95_reason"])
    edge = (
        " The band-edge reference (perfect forecast) saves "
        + html.escape(
            savings_text(
                s["edge_savings_pct"], s["edge_savings_ci95_pct"], s["edge_savings_ci95_reason"]
            )
        )
        + "."
        if "edge_savings_pct" in s
        else ""
    )
    head = (
        f"<h1>Fleet study: {s['coaches']} coaches × {s['days']} days</h1>"
        f"<p>{s['coach_days']} coach-days, the DDPC layer with the "
        f"{html.escape(s['study']['forecast'])} forecast. Headline meter: the HVAC units "
        f"({s['meter']}). Rule-based {fmt_num(s['energy_rule_kwh'] / 1e3, '.1f')} MWh, DDPC layer "
        f"{fmt_num(s['energy_ddpc_kwh'] / 1e3, '.1f')} MWh: "
        f"<b>{html.escape(saving)}</b> "
        f"saved ({fmt_num(s['saved_mwh'], '.1f')} MWh, {fmt_num(s['saved_chf'], ',.0f')} CHF at "
        f"{s['price_chf_per_kwh']:g} CHF/kWh, {fmt_num(s['saved_t_co2'], '.2f')} t CO₂-eq at "
        f"{s['co2_kg_per_kwh']:g} kg/kWh); whole coach "
        f"{fmt_num(s['savings_by_meter_pct']['hvac_and_floor'], '.2f')} %. "
        "Average hourly violation "
        f"{fmt_num(s['avg_hourly_violation_k'], '.4f')} K (rule-based "
        f"{fmt_num(s['avg_hourly_violation_rule_k'], '.4f')} K).{edge} The intervals: "
        "a two-way bootstrap over coaches and days.</p>"
        "<table border=1 cellpadding=4><tr><th>situation</th><th>hours (thousands)</th>"
        "<th>rule (MWh)</th><th>DDPC (MWh)</th><th>savings (95 % CI)</th>"
        f"<th>avg hourly violation (K)</th></tr>{rows}</table>"
    )
    figures = [_monthly(s), _vs_temperature(frame), _coaches(s), _comfort(s)]
    parts = [head] + [
        fig.to_html(full_html=False, include_plotlyjs=(i == 0)) for i, fig in enumerate(figures)
    ]
    page = html_page("trainclimate fleet study", "\n".join(parts))
    path.write_text(page, encoding="utf-8")
    return path
