"""Table II step by step: what each of the paper's stated conditions does to the savings.

The paired experiments (:mod:`trainclimate.analysis.experiment`) reproduce four conditions the
paper's text states. :func:`run_ablation` adds them one at a time, in this order, and measures
every step on every experiment:

1. ``before``: the experiments as they were read first — every meter counts the floor and wall
   heating, the HVAC state between its ambient thresholds is always mixed, and only the field
   events :data:`EARLIER_EVENTS` are modelled;
2. ``hvac_meter``: the savings on the HVAC units alone, what the paper's external loggers metered
   (Section V);
3. ``october``: the HVAC state chosen by the room between the ambient thresholds
   (``climate_from_room``, Section II.B names the room temperature as an input of the state
   block), which makes Experiment 1's coaches cool;
4. ``field_events``: every connection loss and command override the paper reports, and the
   cooling's switching limit it suspects (:data:`~trainclimate.analysis.experiment.EXPERIMENTS`);
5. ``sensor_violation``: the violation from the onboard sensors' readings, as the paper could
   measure it (step 4's run).

Each step gives the activated coach's savings and the band-edge reference's, the violation, and
the share of the counted time the deactivated coach spent cooling.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from trainclimate.analysis.experiment import EXPERIMENTS, Event, PairResult, run_pair
from trainclimate.analysis.report import PAPER_TABLE, fmt_num
from trainclimate.predict.base import MultistepPredictor
from trainclimate.sim.params import CoachParams

#: The steps, in order, and their column titles.
STEPS = {
    "before": "as before",
    "hvac_meter": "+ HVAC meter",
    "october": "+ October conditions",
    "field_events": "+ field events",
    "sensor_violation": "+ sensor violation",
}

#: The field events the experiments modelled before the ``field_events`` step.
EARLIER_EVENTS: dict[str, tuple[Event, ...]] = {
    "parked-cooling-oct": (Event("connection_loss", "activated", "17:50"),),
    "parked-heating-nov": (Event("command_override", "activated", "13:30", 30.0),),
}

#: The HVAC states that cool.
COOLING_STATES = ("cooling", "precooling", "slumber_cooling")


def _step(pair: PairResult, meter: str, sensors: bool = False) -> dict:
    """One step's figures from a run: savings and band-edge savings on ``meter`` (%), the
    violation (K, true or from the sensors) and the deactivated coach's cooling share (–)."""
    act, edge = pair.by_meter[meter]
    share = pair.state_share["deactivated"]
    return {
        "savings_pct": act.savings_pct,
        "edge_savings_pct": edge.savings_pct,
        "avg_hourly_violation_k": pair.violation_sensor_k
        if sensors
        else act.avg_hourly_violation_k,
        "deactivated_cooling_share": sum(share.get(s, 0.0) for s in COOLING_STATES),
    }


def ablate(
    name: str,
    predictor: MultistepPredictor,
    *,
    forecast: str = "perfect",
    base_params: CoachParams | None = None,
) -> dict:
    """The five steps of one experiment (see the module docstring).

    Parameters
    ----------
    name : str
        An experiment's scenario, a key of :data:`~trainclimate.analysis.experiment.EXPERIMENTS`.
    predictor : MultistepPredictor
        The DDPC layer's prediction model.
    forecast : str, default "perfect"
        The activated coach's forecast.
    base_params : CoachParams, optional
        The coaches' parameters (default: the scenario's).

    Returns
    -------
    dict
        ``scenario``, ``paper`` (its Table II savings % and violation K, or None) and
        ``steps``: step → ``savings_pct``, ``edge_savings_pct`` (%), ``avg_hourly_violation_k``
        (K) and ``deactivated_cooling_share`` (–).
    """
    setup = EXPERIMENTS[name]
    earlier = dataclasses.replace(setup, events=EARLIER_EVENTS.get(name, ()), hvac_options={})
    kw = {"forecast": forecast, "base_params": base_params, "objective": "paper"}
    ambient_only = dataclasses.replace(earlier, hvac_options={"climate_from_room": 0.0})
    first = run_pair(name, predictor, setup=ambient_only, **kw)
    october = run_pair(name, predictor, setup=earlier, **kw)
    full = run_pair(name, predictor, setup=setup, **kw)
    paper = PAPER_TABLE.get(name)
    return {
        "scenario": name,
        "paper": None if paper is None else {"savings_pct": paper[0], "violation_k": paper[1]},
        "steps": {
            "before": _step(first, "hvac_and_floor"),
            "hvac_meter": _step(first, "hvac"),
            "october": _step(october, "hvac"),
            "field_events": _step(full, "hvac"),
            "sensor_violation": _step(full, "hvac", sensors=True),
        },
    }


def run_ablation(
    predictor: MultistepPredictor,
    *,
    forecast: str = "perfect",
    base_params: CoachParams | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[dict]:
    """:func:`ablate` for every experiment, in :data:`EXPERIMENTS` order; ``progress(name)`` is
    called after each."""
    rows = []
    for name in EXPERIMENTS:
        rows.append(ablate(name, predictor, forecast=forecast, base_params=base_params))
        if progress:
            progress(name)
    return rows


def ablation_markdown(rows: list[dict]) -> str:
    """The ablation as a Markdown table: per experiment and step, the savings with the band-edge
    reference's in brackets, the violation, and the paper's figures.

    Parameters
    ----------
    rows : list of dict
        :func:`ablate` of each experiment.

    Returns
    -------
    str
        The Markdown text, ending with a newline.
    """
    titles = " | ".join(STEPS.values())
    lines = [
        f"| experiment | {titles} | paper |",
        "| --- |" + " --- |" * (len(STEPS) + 1),
    ]
    for r in rows:
        cells = [
            f"{fmt_num(s['savings_pct'], '.2f')} ({fmt_num(s['edge_savings_pct'], '.2f')}); "
            f"{s['avg_hourly_violation_k']:.4f} K; "
            f"cooling {100 * s['deactivated_cooling_share']:.0f} %"
            for s in (r["steps"][k] for k in STEPS)
        ]
        paper = r["paper"]
        ref = "–" if paper is None else f"{paper['savings_pct']:.2f}; {paper['violation_k']:.4f} K"
        lines.append(f"| {r['scenario']} | {' | '.join(cells)} | {ref} |")
    return "\n".join(lines) + "\n"


def write_ablation(rows: list[dict], out: str | Path) -> Path:
    """Write ``ablation.md`` (:func:`ablation_markdown`) into ``out`` (created if missing) and
    return its path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "ablation.md"
    path.write_text(ablation_markdown(rows), encoding="utf-8")
    return path
