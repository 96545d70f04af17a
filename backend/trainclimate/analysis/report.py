"""Self-contained HTML reports with Plotly figures (plotly.js embedded: no CDN needed)."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from trainclimate.analysis.summary import fleet_kpis
from trainclimate.coach.meters import HEADLINE_METER, METER_LABELS
from trainclimate.coach.rule import MODE_NAMES
from trainclimate.coach.states import STATE_NAMES
from trainclimate.sim import thermal
from trainclimate.sim.scenarios import LOCAL_TZ, Scenario
from trainclimate.sim.simulator import DECKS, SimulationResult

DECK_COLOURS = {"up": "#d62728", "mid": "#2ca02c", "low": "#1f77b4"}
#: Plotted resolution: one point per minute keeps a day's report small and fast.
PLOT_STEP_S = 60.0


def _local(result: SimulationResult):
    return result.time.tz_convert(LOCAL_TZ).tz_localize(None)[_every(result)]


def _every(result: SimulationResult) -> slice:
    """Every sample at most once per :data:`PLOT_STEP_S`."""
    return slice(None, None, max(1, round(PLOT_STEP_S / result.dt_s)))


def _add_deck_traces(fig: go.Figure, t, result: SimulationResult, coach: int, row: int, **extra):
    """Add the deck temperatures of ``coach`` (every :func:`_every` sample) to row ``row``."""
    e = _every(result)
    for d, deck in enumerate(DECKS):
        fig.add_trace(
            go.Scatter(
                x=t,
                y=result.t_room_c[e, coach, d],
                name=f"T_room {deck}",
                line={"color": DECK_COLOURS[deck], "width": 1.2},
                **extra,
            ),
            row=row,
            col=1,
        )


def temperature_figure(result: SimulationResult, title: str, coach: int = 0) -> go.Figure:
    """Deck temperatures (°C) with T_ref and the T_rule ± 1 K band; T_amb and irradiance below.

    Parameters
    ----------
    result : SimulationResult
        The run, plotted at most once per :data:`PLOT_STEP_S` in local time (Europe/Zurich).
    title : str
    coach : int, default 0

    Returns
    -------
    plotly.graph_objects.Figure
    """
    t = _local(result)
    fig = make_subplots(
        rows=2,
        cols=1,
        shared_xaxes=True,
        row_heights=[0.65, 0.35],
        specs=[[{}], [{"secondary_y": True}]],
        vertical_spacing=0.06,
    )
    e = _every(result)
    rule = result.t_rule_c[e, coach]
    fig.add_trace(
        go.Scatter(x=t, y=rule + 1.0, line={"width": 0}, showlegend=False, hoverinfo="skip"),
        row=1,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=t,
            y=rule - 1.0,
            fill="tonexty",
            line={"width": 0},
            fillcolor="rgba(120,120,120,0.18)",
            name="T_rule ± 1 K",
        ),
        row=1,
        col=1,
    )
    _add_deck_traces(fig, t, result, coach, 1)
    fig.add_trace(
        go.Scatter(
            x=t, y=result.t_ref_c[e, coach], name="T_ref", line={"color": "black", "dash": "dash"}
        ),
        row=1,
        col=1,
    )
    env = result.env
    s, e = len(result.time), _every(result)
    fig.add_trace(
        go.Scatter(x=t, y=env.t_amb_c[:s][e, coach], name="T_amb", line={"color": "#9467bd"}),
        row=2,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=t, y=env.ghi_w_m2[:s][e, coach], name="global irradiance", line={"color": "#ff7f0e"}
        ),
        row=2,
        col=1,
        secondary_y=True,
    )
    fig.update_yaxes(title_text="temperature (°C)", row=1, col=1)
    fig.update_yaxes(title_text="T_amb (°C)", row=2, col=1)
    fig.update_yaxes(title_text="irradiance (W/m²)", row=2, col=1, secondary_y=True)
    fig.update_xaxes(title_text="local time (Europe/Zurich)", row=2, col=1)
    fig.update_layout(title=title, height=620, template="plotly_white")
    return fig


def power_figure(result: SimulationResult, title: str, coach: int = 0) -> go.Figure:
    """Electrical power by component (stacked, kW) and cumulative energy (kWh).

    Parameters and Returns as in :func:`temperature_figure`.
    """
    t = _local(result)
    fig = make_subplots(specs=[[{"secondary_y": True}]])
    e = _every(result)
    for name, value in result.power_w.items():
        fig.add_trace(
            go.Scatter(
                x=t,
                y=value[e, coach] / 1e3,
                name=name.replace("_", "/"),
                stackgroup="power",
                line={"width": 0.5},
            )
        )
    energy = (np.cumsum(result.total_power_w[:, coach]) * result.dt_s / 3.6e6)[e]
    fig.add_trace(
        go.Scatter(x=t, y=energy, name="cumulative energy", line={"color": "black"}),
        secondary_y=True,
    )
    fig.update_yaxes(title_text="electrical power (kW)")
    fig.update_yaxes(title_text="energy (kWh)", secondary_y=True)
    fig.update_xaxes(title_text="local time (Europe/Zurich)")
    fig.update_layout(title=title, height=420, template="plotly_white")
    return fig


def state_figure(result: SimulationResult, title: str, coach: int = 0) -> go.Figure:
    """HVAC mode and state over time, and the fresh-air fraction (substate).

    Parameters and Returns as in :func:`temperature_figure`.
    """
    t = _local(result)
    s, e = len(result.time), _every(result)
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.08)
    fig.add_trace(
        go.Scatter(
            x=t,
            y=[STATE_NAMES[int(v)] for v in result.hvac_state[e, coach]],
            name="HVAC state",
            mode="lines",
            line={"shape": "hv"},
        ),
        row=1,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=t,
            y=[MODE_NAMES[int(v)] for v in result.env.mode[:s][e, coach]],
            name="HVAC mode",
            mode="lines",
            line={"shape": "hv", "dash": "dot"},
        ),
        row=1,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=t, y=result.fresh_fraction[e, coach], name="fresh-air fraction", line={"shape": "hv"}
        ),
        row=2,
        col=1,
    )
    fig.update_yaxes(title_text="fraction (–)", row=2, col=1)
    fig.update_xaxes(title_text="local time (Europe/Zurich)", row=2, col=1)
    fig.update_layout(title=title, height=460, template="plotly_white")
    return fig


def heat_balance_figure(result: SimulationResult, title: str, coach: int = 0) -> go.Figure:
    """Heat entering the coach over the run by mechanism, kWh (negative: heat leaving).

    Parameters and Returns as in :func:`temperature_figure`; ``result`` must have its heat flows
    recorded (``record_flows=True``).
    """
    ext = result.flows_w[:, coach, thermal.N_INTERNAL :].sum(axis=0) * result.dt_s / 3.6e6
    names = list(thermal.FLOW_NAMES[thermal.N_INTERNAL :])
    fig = go.Figure(go.Bar(x=names, y=ext, marker_color=np.where(ext >= 0, "#d62728", "#1f77b4")))
    fig.update_yaxes(title_text="heat into the coach (kWh)")
    fig.update_layout(title=title, height=420, template="plotly_white")
    return fig


def fleet_energy_figure(result: SimulationResult, title: str) -> go.Figure:
    """Electrical energy of every coach over the run, kWh, as bars.

    Parameters
    ----------
    result : SimulationResult
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
    """
    energy = result.energy_kwh
    fig = go.Figure(go.Bar(x=[f"coach {i}" for i in range(len(energy))], y=energy))
    fig.update_yaxes(title_text="electrical energy (kWh)")
    fig.update_layout(title=title, height=360, template="plotly_white")
    return fig


def write_simulation_report(
    results: dict[str, SimulationResult], scenario: Scenario, path: str | Path
) -> Path:
    """Write one self-contained HTML page for a scenario simulated with one or more controllers.

    Parameters
    ----------
    results : dict of str to SimulationResult
        Controller name → its run.
    scenario : Scenario
    path : str or pathlib.Path
        Destination file.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    parts = [f"<h1>{html.escape(scenario.name)}</h1><p>{html.escape(scenario.description)}</p>"]
    first = True
    for controller, result in results.items():
        kpis = fleet_kpis(result)
        rows = "".join(
            f"<tr><td>{i}</td><td>{c['energy_kwh']:.1f}</td><td>{c['mean_power_kw']:.2f}</td>"
            f"<td>{c['avg_hourly_violation_k']:.4f}</td><td>{c['discomfort_kh']:.3f}</td></tr>"
            for i, c in enumerate(kpis["coaches"])
        )
        parts.append(
            f"<h2>controller: {html.escape(controller)}</h2>"
            "<table border=1 cellpadding=4><tr><th>coach</th><th>energy (kWh)</th>"
            "<th>mean power (kW)</th><th>avg hourly violation (K)</th>"
            f"<th>discomfort (K·h per deck)</th></tr>{rows}</table>"
        )
        figures = [
            temperature_figure(result, f"{controller}: coach 0 deck temperatures"),
            power_figure(result, f"{controller}: coach 0 electrical power"),
            state_figure(result, f"{controller}: coach 0 HVAC mode, state and substate"),
        ]
        if result.flows_w is not None:
            figures.append(heat_balance_figure(result, f"{controller}: coach 0 heat balance"))
        if result.t_ref_c.shape[1] > 1:
            figures.append(fleet_energy_figure(result, f"{controller}: energy per coach"))
        for fig in figures:
            parts.append(fig.to_html(full_html=False, include_plotlyjs=first))
            first = False
    path.write_text(html_page("trainclimate report", "\n".join(parts)), encoding="utf-8")
    return path


def html_page(title: str, body: str) -> str:
    """A self-contained HTML page: ``title`` (escaped here) and ``body`` (HTML)."""
    return (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        "<style>body{font-family:sans-serif;max-width:1400px;margin:auto}</style></head><body>"
        + body
        + "</body></html>"
    )


def experiment_figure(pair, title: str = "") -> go.Figure:
    """The paper's experiment figure (Figures 7–10) for a paired experiment.

    The deactivated coach (deck temperatures, T_ref, the T_rule ± 1 K band), the activated coach
    (the same), T_amb and solar irradiance, and the cumulative energy of both with the 30-minute
    savings as bars; excluded windows shaded, the counted period starting at the dashed line.

    Parameters
    ----------
    pair : PairResult
        From :func:`~trainclimate.analysis.experiment.run_pair`.
    title : str, default ""

    Returns
    -------
    plotly.graph_objects.Figure
    """
    from trainclimate.analysis.experiment import ACTIVATED, DEACTIVATED

    result, comp = pair.result, pair.comparison
    e = _every(result)
    t = _local(result)
    fig = make_subplots(
        rows=4,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.05,
        row_heights=[0.28, 0.28, 0.18, 0.26],
        specs=[[{}], [{}], [{"secondary_y": True}], [{"secondary_y": True}]],
        subplot_titles=(
            "Deactivated DDPC (T_ref = T_rule)",
            "Activated DDPC",
            "Weather",
            "Energy and 30-minute savings",
        ),
    )
    for row, coach in ((1, DEACTIVATED), (2, ACTIVATED)):
        rule = result.t_rule_c[e, coach]
        for offset, name in ((1.0, "upper bound"), (-1.0, "lower bound")):
            fig.add_trace(
                go.Scatter(
                    x=t,
                    y=rule + offset,
                    name=name,
                    showlegend=row == 1,
                    line={"color": "grey", "dash": "dot", "width": 1},
                ),
                row=row,
                col=1,
            )
        _add_deck_traces(fig, t, result, coach, row, showlegend=row == 1)
        fig.add_trace(
            go.Scatter(
                x=t,
                y=result.t_ref_c[e, coach],
                name="T_ref",
                showlegend=row == 1,
                line={"color": "black", "dash": "dash"},
            ),
            row=row,
            col=1,
        )
        fig.update_yaxes(title_text="°C", row=row, col=1)
    env = result.env
    fig.add_trace(
        go.Scatter(
            x=t, y=env.t_amb_c[: len(result.time)][e, 0], name="T_amb", line={"color": "#9467bd"}
        ),
        row=3,
        col=1,
    )
    fig.add_trace(
        go.Scatter(
            x=t,
            y=env.ghi_w_m2[: len(result.time)][e, 0],
            name="global irradiance",
            line={"color": "#ff7f0e"},
        ),
        row=3,
        col=1,
        secondary_y=True,
    )
    fig.update_yaxes(title_text="T_amb (°C)", row=3, col=1)
    fig.update_yaxes(
        title_text="W/m²", row=3, col=1, secondary_y=True, tickmode="auto", rangemode="tozero"
    )
    dt_h = result.dt_s / 3600.0
    meter = METER_LABELS[HEADLINE_METER]
    for coach, name, colour in (
        (DEACTIVATED, f"energy ({meter}), deactivated", "#7f7f7f"),
        (ACTIVATED, f"energy ({meter}), activated", "#2ca02c"),
    ):
        power_w = result.meter_w(HEADLINE_METER)[:, coach]
        cumulative = np.cumsum(np.nan_to_num(power_w) / 1e3 * dt_h)
        fig.add_trace(
            go.Scatter(x=t, y=cumulative[e], name=name, line={"color": colour}),
            row=4,
            col=1,
        )
    mids = comp.window_start + pd.Timedelta(minutes=comp.window_min / 2)
    local_mids = mids.tz_convert(LOCAL_TZ).tz_localize(None)
    savings = [np.nan if s is None else s for s in comp.savings_30min_pct]
    fig.add_trace(
        go.Bar(
            x=local_mids,
            y=savings,
            name="30-min savings (%)",
            marker_color="#17becf",
            opacity=0.6,
            width=comp.window_min * 60e3 * 0.8,
        ),
        row=4,
        col=1,
        secondary_y=True,
    )
    fig.update_yaxes(title_text="kWh", row=4, col=1)
    fig.update_yaxes(
        title_text="savings (%)",
        row=4,
        col=1,
        secondary_y=True,
        tickmode="auto",
        showgrid=False,
    )
    for start, excluded in zip(comp.window_start, comp.excluded, strict=True):
        if excluded:
            a = start.tz_convert(LOCAL_TZ).tz_localize(None)
            fig.add_vrect(
                x0=a,
                x1=a + pd.Timedelta(minutes=comp.window_min),
                fillcolor="red",
                opacity=0.12,
                line_width=0,
            )
    counted = pair.counted_from.tz_convert(LOCAL_TZ).tz_localize(None)
    fig.add_vline(x=counted, line_dash="dash", line_color="black")
    fig.update_xaxes(title_text="local time (Europe/Zurich)", row=4, col=1)
    fig.update_layout(title=title, height=1100, template="plotly_white")
    return fig


def fmt_num(v, fmt: str) -> str:
    """``v`` formatted with ``fmt``, or "–" when it is None."""
    return "–" if v is None else format(v, fmt)


def summary_table_html(rows: list[dict]) -> str:
    """The summary table in the paper's format (Table II) plus the KPIs beside it, as HTML.

    Parameters
    ----------
    rows : list of dict
        :meth:`~trainclimate.analysis.experiment.PairResult.to_dict` of each experiment.

    Returns
    -------
    str
        An HTML ``<table>``.
    """
    head = (
        f"<tr><th>scenario</th><th>energy savings, {METER_LABELS[HEADLINE_METER]} (%)</th>"
        f"<th>energy savings, {METER_LABELS['hvac_and_floor']} (%)</th>"
        "<th>average hourly violation (K)</th><th>the same from the sensors (K)</th>"
        "<th>deactivated coach's violation (K)</th><th>band-edge savings (%)</th>"
        "<th>share of band-edge (%)</th><th>energy act./deact. (kWh)</th>"
        "<th>discomfort act. (K·h per deck)</th><th>excluded minutes</th>"
        "<th>computational time ratio</th></tr>"
    )

    body = "".join(
        f"<tr><td>{html.escape(r['scenario'])}</td><td>{fmt_num(r['savings_pct'], '.2f')}</td>"
        f"<td>{fmt_num(r['savings_by_meter_pct']['hvac_and_floor'], '.2f')}</td>"
        f"<td>{r['avg_hourly_violation_k']:.4f}</td>"
        f"<td>{r['avg_hourly_violation_sensor_k']:.4f}</td><td>{r['baseline_violation_k']:.4f}</td>"
        f"<td>{fmt_num(r['edge_savings_pct'], '.2f')}</td>"
        f"<td>{fmt_num(r['share_of_edge_pct'], '.0f')}</td>"
        f"<td>{r['energy_activated_kwh']:.1f} / {r['energy_deactivated_kwh']:.1f}</td>"
        f"<td>{', '.join(f'{v:.3f}' for v in r['discomfort_kh'])}</td>"
        f"<td>{r['excluded_minutes']:.0f}</td><td>{r['computational_time_ratio']:.1e}</td></tr>"
        for r in rows
    )
    return f"<table border=1 cellpadding=4>{head}{body}</table>"


def write_experiment_report(pair, path: str | Path) -> Path:
    """Write a self-contained HTML page for one paired experiment: figure and summary.

    Parameters
    ----------
    pair : PairResult
    path : str or pathlib.Path
        Destination file; its directory is created.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = pair.to_dict()
    scenario = pair.scenario
    page = html_page(
        f"{scenario.name} — paired experiment",
        f"<h1>{html.escape(scenario.name)}: activated vs deactivated</h1>"
        f"<p>{html.escape(scenario.description)}. {html.escape(pair.setup.note)}</p>"
        + summary_table_html([data])
        + experiment_figure(pair).to_html(full_html=False, include_plotlyjs=True),
    )
    path.write_text(page, encoding="utf-8")
    return path


#: The paper's Table II (Section V): savings (%) and average hourly violation (K).
PAPER_TABLE = {
    "parked-cooling-oct": (28.03, 0.0173),
    "parked-cooling-aug-conservative": (20.11, 0.0014),
    "parked-cooling-aug-energy": (34.94, 0.0609),
    "parked-heating-nov": (11.65, 0.0404),
}


def summary_markdown(rows: list[dict]) -> str:
    """The summary as a Markdown table: the paper's Table II figures beside ours, and the KPIs.

    Parameters
    ----------
    rows : list of dict
        As in :func:`summary_table_html`.

    Returns
    -------
    str
        The Markdown text, ending with a newline.
    """
    lines = [
        f"| scenario | savings, {METER_LABELS[HEADLINE_METER]} (%) | paper (%) | "
        f"savings, {METER_LABELS['hvac_and_floor']} (%) | avg hourly violation (K) | "
        "from the sensors (K) | paper (K) | "
        "deactivated coach (K) | band-edge savings (%) | share of band-edge (%) | "
        "energy act. / deact. (kWh) | discomfort act. (K·h/deck) | excluded (min) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        paper = PAPER_TABLE.get(r["scenario"])
        lines.append(
            f"| {r['scenario']} | {fmt_num(r['savings_pct'], '.2f')} | "
            f"{fmt_num(paper and paper[0], '.2f')} | "
            f"{fmt_num(r['savings_by_meter_pct']['hvac_and_floor'], '.2f')} | "
            f"{r['avg_hourly_violation_k']:.4f} | {r['avg_hourly_violation_sensor_k']:.4f} | "
            f"{fmt_num(paper and paper[1], '.4f')} | {r['baseline_violation_k']:.4f} | "
            f"{fmt_num(r['edge_savings_pct'], '.2f')} | {fmt_num(r['share_of_edge_pct'], '.0f')} | "
            f"{r['energy_activated_kwh']:.1f} / {r['energy_deactivated_kwh']:.1f} | "
            f"{sum(r['discomfort_kh']) / 3:.3f} | {r['excluded_minutes']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def write_summary(rows: list[dict], out: str | Path) -> dict[str, Path]:
    """Write ``summary.md`` and ``summary.html`` (the table in the paper's format, linked reports).

    Parameters
    ----------
    rows : list of dict
        :meth:`~trainclimate.analysis.experiment.PairResult.to_dict` of each experiment; an
        ``html`` key links its report.
    out : str or pathlib.Path
        Output directory; created if missing.

    Returns
    -------
    dict of str to pathlib.Path
        ``markdown`` and ``html``: the files written.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    md = out / "summary.md"
    md.write_text(summary_markdown(rows), encoding="utf-8")
    links = "".join(
        f"<li><a href='{html.escape(Path(r['html']).name)}'>{html.escape(r['scenario'])}</a></li>"
        for r in rows
        if "html" in r
    )
    page = html_page(
        "paired experiments",
        "<h1>Paired experiments: summary</h1>" + summary_table_html(rows) + f"<ul>{links}</ul>",
    )
    page_path = out / "summary.html"
    page_path.write_text(page, encoding="utf-8")
    return {"markdown": md, "html": page_path}
