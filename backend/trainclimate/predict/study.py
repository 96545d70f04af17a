"""The paper's three sensitivity studies of the prediction model (Section IV.A, Figure 5).

1. Sampling time 1, 5 and 10 min with a 60-min lead-in and a 30-min horizon
   (ρ, T) = (60, 30), (12, 6), (6, 3).
2. Lead-in ρ ∈ {3, 6, 9, 12, 18, 24} at 5 min with a 30-min horizon (T = 6).
3. Horizon T ∈ {3, 6, 9, 12} at 5 min with ρ = 6.

Each with all three methods, trained on the training coaches and measured on the held-out ones
(:mod:`~trainclimate.predict.evaluate`); plus a target setting, 5 min with ρ = T = 12.
:func:`write_report` draws them as a self-contained HTML page with Plotly figures.
"""

from __future__ import annotations

import html
from collections.abc import Callable
from pathlib import Path

import plotly.graph_objects as go
from plotly.subplots import make_subplots

from trainclimate.predict import METHODS
from trainclimate.predict.evaluate import evaluate, load_split

STUDIES = {
    "sampling": [(1, 60, 30), (5, 12, 6), (10, 6, 3)],
    "lead_in": [(5, rho, 6) for rho in (3, 6, 9, 12, 18, 24)],
    "horizon": [(5, 6, T) for T in (3, 6, 9, 12)],
    "target": [(5, 12, 12)],
}
TITLES = {
    "sampling": "Sampling time (60-min lead-in, 30-min horizon)",
    "lead_in": "Lead-in ρ at 5 min (T = 6)",
    "horizon": "Horizon T at 5 min (ρ = 6)",
    "target": "Target setting: 5 min, ρ = T = 12",
}
METHOD_STYLE = {
    "transient": "solid",
    "subspace": "dash",
    "arx": "dot",
    "subspace-causal": "dashdot",
}


def run_studies(
    data_dir: str | Path, progress: Callable[[int], None] | None = None
) -> dict[str, list[dict]]:
    """Evaluate every setting of :data:`STUDIES` with every method.

    Parameters
    ----------
    data_dir : str or pathlib.Path
        Directory of the trajectory files (:func:`~trainclimate.predict.evaluate.load_split`).
    progress : callable, optional
        Called with 1 after each of the :func:`n_runs` evaluations.

    Returns
    -------
    dict of str to list of dict
        Study name → the :func:`~trainclimate.predict.evaluate.evaluate` dicts of its settings
        and methods.

    Raises
    ------
    PredictorDataError
        If a sampling time's data are missing, too few or rank-deficient.

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Section IV.A, Figure 5.
    """
    splits: dict[int, tuple] = {}
    out: dict[str, list[dict]] = {}
    for study, settings in STUDIES.items():
        out[study] = []
        for sampling, rho, horizon in settings:
            if sampling not in splits:
                splits[sampling] = load_split(data_dir, sampling)
            for method in METHODS:
                _, result = evaluate(
                    method, sampling, rho, horizon, data_dir, split=splits[sampling]
                )
                out[study].append(result)
                if progress:
                    progress(1)
    return out


def n_runs() -> int:
    """Number of evaluations :func:`run_studies` performs.

    Returns
    -------
    int
        Settings of :data:`STUDIES` × methods of :data:`~trainclimate.predict.METHODS`.
    """
    return sum(len(s) for s in STUDIES.values()) * len(METHODS)


def _label(result: dict, study: str) -> str:
    return {
        "sampling": f"{result['sampling_min']} min",
        "lead_in": f"ρ = {result['rho']}",
        "horizon": f"T = {result['horizon']}",
        "target": "ρ = T = 12",
    }[study]


def figure(results: dict[str, list[dict]]) -> go.Figure:
    """Plot MAE (mean over decks, K) against prediction time (min).

    Parameters
    ----------
    results : dict of str to list of dict
        The output of :func:`run_studies`.

    Returns
    -------
    plotly.graph_objects.Figure
        A column per study, a row per method, with the paper's 0.25 K line.
    """
    studies = [s for s in STUDIES if s in results]
    methods = list(METHODS)
    fig = make_subplots(
        rows=len(methods),
        cols=len(studies),
        shared_yaxes=True,
        subplot_titles=[f"{m} — {TITLES[s]}" for m in methods for s in studies],
        vertical_spacing=0.08,
        horizontal_spacing=0.04,
    )
    palette = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b"]
    for r, method in enumerate(methods, start=1):
        for c, study in enumerate(studies, start=1):
            rows = [x for x in results[study] if x["method"] == method]
            for k, res in enumerate(rows):
                fig.add_trace(
                    go.Scatter(
                        x=res["prediction_minutes"],
                        y=res["mae_per_step_c"],
                        mode="lines+markers",
                        name=_label(res, study),
                        legendgroup=f"{study}-{k}",
                        showlegend=r == 1,
                        line={"color": palette[k % len(palette)], "dash": METHOD_STYLE[method]},
                    ),
                    row=r,
                    col=c,
                )
            fig.update_xaxes(title_text="prediction time (min)", row=r, col=c)
        fig.update_yaxes(title_text="MAE (K)", row=r, col=1)
    fig.add_hline(y=0.25, line_dash="dot", line_color="grey", annotation_text="0.25 K")
    fig.update_layout(height=330 * len(methods), width=420 * len(studies), template="plotly_white")
    return fig


def summary_rows(results: dict[str, list[dict]]) -> list[dict]:
    """Tabulate the studies: one row per study and setting.

    Parameters
    ----------
    results : dict of str to list of dict
        Study name → its results, as :func:`run_studies` returns them.

    Returns
    -------
    list of dict
        ``study``, ``sampling_min``, ``rho``, ``horizon``, per method ``{m}_mean_mae_c`` and
        ``{m}_max_step_mae_c`` (K), and ``best`` (the method of lowest mean MAE).
    """
    rows = []
    for study, res in results.items():
        settings: dict[tuple[int, int, int], dict[str, dict]] = {}
        for r in res:
            key = (r["sampling_min"], r["rho"], r["horizon"])
            settings.setdefault(key, {})[r["method"]] = r
        for (sampling, rho, horizon), by_method in settings.items():
            row = {"study": study, "sampling_min": sampling, "rho": rho, "horizon": horizon}
            for method, r in by_method.items():
                row[f"{method}_mean_mae_c"] = r["mae_mean_c"]
                row[f"{method}_max_step_mae_c"] = max(r["mae_per_step_c"])
            row["best"] = min(by_method, key=lambda m: by_method[m]["mae_mean_c"])
            rows.append(row)
    return rows


def write_report(results: dict[str, list[dict]], path: str | Path) -> Path:
    """Write a self-contained HTML page: the figure and the summary table.

    Parameters
    ----------
    results : dict of str to list of dict
        The output of :func:`run_studies`.
    path : str or pathlib.Path
        Destination file; its directory is created.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = summary_rows(results)
    head = "".join(
        f"<th>{html.escape(h)}</th>"
        for h in ("study", "sampling", "ρ", "T", *(f"{m} mean MAE (K)" for m in METHODS), "best")
    )
    body = "".join(
        "<tr>"
        + "".join(
            f"<td>{v}</td>"
            for v in (
                r["study"],
                f"{r['sampling_min']} min",
                r["rho"],
                r["horizon"],
                *(f"{r[f'{m}_mean_mae_c']:.4f}" for m in METHODS),
                r["best"],
            )
        )
        + "</tr>"
        for r in rows
    )
    validation = next(iter(results.values()))[0]
    page = f"""<!doctype html><html><head><meta charset="utf-8">
<title>trainclimate — prediction model evaluation</title>
<style>body{{font-family:sans-serif;margin:2em}}
td,th{{padding:4px 10px;border-bottom:1px solid #ddd}}</style></head><body>
<h1>Prediction model evaluation (paper, Section IV.A, Figure 6)</h1>
<p>Trained on coaches {html.escape(", ".join(validation["train_coaches"]))}; validated on the
held-out coaches {html.escape(", ".join(validation["validation_coaches"]))}. MAE over every sliding
window of the validation trajectories, mean over the three decks. Transient solid, subspace dashed,
ARX dotted, and the causal subspace ablation dash-dotted.</p>
{figure(results).to_html(full_html=False, include_plotlyjs=True)}
<h2>Mean MAE over the horizon</h2><table><tr>{head}</tr>{body}</table>
</body></html>"""
    path.write_text(page, encoding="utf-8")
    return path
