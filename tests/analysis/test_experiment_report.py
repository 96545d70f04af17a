"""The paired experiment's report: the four-panel figure, the self-contained page and the summary
in the paper's format (analysis.report)."""

from __future__ import annotations

import copy

import numpy as np
import pandas as pd
import pytest
from plotly.offline import get_plotlyjs

from trainclimate.analysis.experiment import ACTIVATED, DEACTIVATED
from trainclimate.analysis.report import (
    PAPER_TABLE,
    experiment_figure,
    summary_markdown,
    summary_table_html,
    write_experiment_report,
    write_summary,
)
from trainclimate.sim.scenarios import LOCAL_TZ
from trainclimate.sim.simulator import DECKS

SUBPLOT_TITLES = (
    "Deactivated DDPC (T_ref = T_rule)",
    "Activated DDPC",
    "Weather",
    "Energy and 30-minute savings",
)
PLOT_EVERY = 6  # one point a minute of the 10-s steps
PARKED = (
    "parked-cooling-oct",
    "parked-cooling-aug-conservative",
    "parked-cooling-aug-energy",
    "parked-heating-nov",
)


def naive_local(t) -> pd.Timestamp:
    return pd.Timestamp(t).tz_convert(LOCAL_TZ).tz_localize(None)


# --- the figure ---------------------------------------------------------------------------------
def test_the_figure_has_both_coaches_weather_energy_and_savings(heating_loss):
    pair = heating_loss.pair
    result, comp = pair.result, pair.comparison
    fig = experiment_figure(pair, "title")
    names = [t.name for t in fig.data]
    coach_traces = [
        "upper bound",
        "lower bound",
        *(f"T_room {deck}" for deck in DECKS),
        "T_ref",
    ]
    assert names == [
        *coach_traces,  # row 1: the deactivated coach
        *coach_traces,  # row 2: the activated coach
        "T_amb",
        "global irradiance",
        "energy (HVAC units), deactivated",
        "energy (HVAC units), activated",
        "30-min savings (%)",
    ]
    e = slice(None, None, PLOT_EVERY)
    x = result.time.tz_convert(LOCAL_TZ).tz_localize(None)[e]
    for row, (axis, coach) in enumerate((("y", DEACTIVATED), ("y2", ACTIVATED))):
        traces = fig.data[6 * row : 6 * row + 6]
        assert {t.yaxis for t in traces} == {axis}
        rule = result.t_rule_c[e, coach]
        np.testing.assert_array_equal(traces[0].y, rule + 1.0)
        np.testing.assert_array_equal(traces[1].y, rule - 1.0)
        for d in range(3):
            np.testing.assert_array_equal(traces[2 + d].y, result.t_room_c[e, coach, d])
        np.testing.assert_array_equal(traces[5].y, result.t_ref_c[e, coach])
        np.testing.assert_array_equal(pd.DatetimeIndex(traces[5].x), x)
    t_amb, ghi = fig.data[12], fig.data[13]
    assert (t_amb.yaxis, ghi.yaxis) == ("y3", "y4")  # irradiance on the secondary axis
    np.testing.assert_array_equal(t_amb.y, result.env.t_amb_c[: len(result.time)][e, 0])
    np.testing.assert_array_equal(ghi.y, result.env.ghi_w_m2[: len(result.time)][e, 0])
    # cumulative energy in kWh, the last plotted point at minute 209 of the 3.5 h
    for trace, coach in ((fig.data[14], DEACTIVATED), (fig.data[15], ACTIVATED)):
        assert trace.yaxis == "y5" and len(trace.y) == 210
        last = len(result.time) - PLOT_EVERY
        expected = result.meter_w("hvac")[: last + 1, coach].sum() / 1e3 * result.dt_s / 3600
        assert trace.y[-1] == pytest.approx(expected, rel=1e-12)
        assert np.all(np.diff(trace.y) >= 0)
    bars = fig.data[16]
    assert bars.type == "bar" and bars.yaxis == "y6"
    expected = [np.nan if s is None else s for s in comp.savings_30min_pct]
    np.testing.assert_array_equal(bars.y, expected)  # excluded windows: no bar
    mids = [naive_local(w + pd.Timedelta(minutes=15)) for w in comp.window_start]
    assert list(pd.DatetimeIndex(bars.x)) == mids
    # the excluded windows (08:45 and 09:45 local) shaded in each of the four panels
    rects = [s for s in fig.layout.shapes if s.type == "rect"]
    excluded = [
        naive_local(w) for w, x_ in zip(comp.window_start, comp.excluded, strict=True) if x_
    ]
    assert len(excluded) == 2
    for xref in ("x", "x2", "x3", "x4"):
        mine = [s for s in rects if s.xref == xref]
        assert [pd.Timestamp(s.x0) for s in mine] == excluded
        assert [pd.Timestamp(s.x1) for s in mine] == [
            a + pd.Timedelta(minutes=30) for a in excluded
        ]
    assert len(rects) == 4 * 2
    # the counted period starts at the dashed line
    lines = [s for s in fig.layout.shapes if s.type == "line"]
    assert {pd.Timestamp(s.x0) for s in lines} == {naive_local(pair.counted_from)}
    assert [a.text for a in fig.layout.annotations] == list(SUBPLOT_TITLES)


def test_nothing_shaded_without_excluded_windows(heating_3h):
    fig = experiment_figure(heating_3h.pair)
    assert not [s for s in fig.layout.shapes if s.type == "rect"]
    assert len(fig.data[-1].y) == 2 and not np.isnan(fig.data[-1].y).any()


# --- the page -----------------------------------------------------------------------------------
def test_the_report_is_a_self_contained_page(heating_loss, tmp_path):
    pair = heating_loss.pair
    path = write_experiment_report(pair, tmp_path / "new" / "dir" / "report.html")
    assert path == tmp_path / "new" / "dir" / "report.html"
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.endswith("</html>")
    bundle = get_plotlyjs()
    assert bundle in text  # plotly.js inline …
    assert "<script src=" not in text  # … and nothing loaded from elsewhere
    # the bundle names cdn.plot.ly once itself (topojson's default URL); the page adds nothing
    assert text.count("cdn.plot.ly") == bundle.count("cdn.plot.ly")
    assert "<title>parked-heating-nov — paired experiment</title>" in text
    assert "<h1>parked-heating-nov: activated vs deactivated</h1>" in text
    for title in SUBPLOT_TITLES:
        assert title in text
    assert pair.scenario.description in text
    # the summary row: savings of the one counted window, 60 min excluded
    assert f"<td>{pair.comparison.savings_pct:.2f}</td>" in text
    assert "<td>60</td>" in text


# --- the summary in the paper's format ----------------------------------------------------------
@pytest.fixture(scope="module")
def rows(heating_3h):
    """One row per paired experiment, built from the short run (numbers aside, the format)."""
    base = heating_3h.pair.to_dict()
    out = [dict(copy.deepcopy(base), scenario=name) for name in ("winter-day", *PARKED)]
    out[1].update(savings_pct=None, edge_savings_pct=None, share_of_edge_pct=None)
    return out


def cells(markdown: str, scenario: str) -> list[str]:
    (line,) = [x for x in markdown.splitlines() if x.startswith(f"| {scenario} |")]
    return [c.strip() for c in line.strip("|").split("|")]


def test_summary_markdown_sets_the_papers_figures_beside_ours(rows):
    md = summary_markdown(rows)
    lines = md.strip().splitlines()
    assert len(lines) == 2 + len(rows)
    assert {line.count("|") for line in lines} == {14}  # 13 columns everywhere
    expected = {
        "parked-cooling-oct": ("28.03", "0.0173"),
        "parked-cooling-aug-conservative": ("20.11", "0.0014"),
        "parked-cooling-aug-energy": ("34.94", "0.0609"),
        "parked-heating-nov": ("11.65", "0.0404"),
    }
    assert set(expected) == set(PAPER_TABLE)
    r = rows[0]
    for name, (savings, violation) in expected.items():
        c = cells(md, name)
        assert (c[2], c[6]) == (savings, violation)
        assert c[3] == f"{r['savings_by_meter_pct']['hvac_and_floor']:.2f}"
        assert c[4] == f"{r['avg_hourly_violation_k']:.4f}"
        assert c[5] == f"{r['avg_hourly_violation_sensor_k']:.4f}"
        assert c[7] == f"{r['baseline_violation_k']:.4f}"
        a, d = r["energy_activated_kwh"], r["energy_deactivated_kwh"]
        assert c[10] == f"{a:.1f} / {d:.1f}"
        assert c[11] == f"{sum(r['discomfort_kh']) / 3:.3f}" and c[12] == "0"
    ours = f"{r['savings_pct']:.2f}"
    assert cells(md, "parked-cooling-aug-conservative")[1] == ours
    # none of ours where a value is undefined, none of the paper's for a scenario it lacks
    missing = cells(md, "parked-cooling-oct")
    assert (missing[1], missing[8], missing[9]) == ("–", "–", "–")
    winter = cells(md, "winter-day")
    assert (winter[1], winter[2], winter[6]) == (ours, "–", "–")


def test_summary_table_html(rows):
    table = summary_table_html(rows)
    assert table.count("<tr>") == 1 + len(rows)
    assert "<td>parked-cooling-oct</td><td>–</td>" in table
    assert f"<td>winter-day</td><td>{rows[0]['savings_pct']:.2f}</td>" in table
    odd = summary_table_html([dict(rows[0], scenario="<b>&")])
    assert "<td>&lt;b&gt;&amp;</td>" in odd


def test_write_summary(rows, tmp_path):
    linked = [dict(r, html=str(tmp_path / "reports" / f"{r['scenario']}.html")) for r in rows[:2]]
    files = write_summary([*linked, *rows[2:]], tmp_path / "out")
    assert files == {
        "markdown": tmp_path / "out" / "summary.md",
        "html": tmp_path / "out" / "summary.html",
    }
    assert files["markdown"].read_text(encoding="utf-8") == summary_markdown([*linked, *rows[2:]])
    page = files["html"].read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>") and summary_table_html(rows) in page
    # links to the reports that exist, by file name (the reports sit beside the summary)
    assert page.count("<li><a href=") == 2
    assert "<li><a href='winter-day.html'>winter-day</a></li>" in page
    assert "<li><a href='parked-cooling-oct.html'>parked-cooling-oct</a></li>" in page
