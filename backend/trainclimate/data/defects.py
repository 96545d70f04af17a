"""The defects of real exports, added to the generated fleet logs (:mod:`.fleetlogs`):
communication gaps, duplicated and out-of-order rows, sensor spikes, empty fields, garbage lines,
unreadable files and the power meter's dropouts, each drawn from a coach-day's seed."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import pandas as pd

from trainclimate.data.formats import ExportFormat
from trainclimate.data.pipeline import _seconds


@dataclass(frozen=True)
class Defects:
    """Rates of the defects added to the exports (per file, per row or per value)."""

    gaps_per_day: float = 1.2
    weather_gaps_per_day: float = 0.3
    gap_min_s: float = 60.0
    gap_max_s: float = 3 * 3600.0
    duplicate_row: float = 0.002
    out_of_order_block: float = 0.3
    spike_value: float = 0.0005
    empty_value: float = 0.0005
    garbage_line: float = 0.05
    unreadable_file: float = 0.003
    missing_trip: float = 0.02
    logger_off_day: float = 0.04
    power_gaps_per_day: float = 0.5
    power_gap_min_s: float = 60.0
    power_gap_max_s: float = 2 * 3600.0

    @classmethod
    def none(cls) -> Defects:
        """A clean export (for tests of the pipeline's fidelity)."""
        return cls(*(0.0,) * len(fields(cls)))


def add_defects(
    table: pd.DataFrame,
    times: pd.DatetimeIndex,
    source: str,
    fmt: ExportFormat,
    rates: Defects,
    rng: np.random.Generator,
) -> tuple[pd.DataFrame, bool]:
    """Export text with defects added; returns it and whether the file is to be unreadable."""
    n = len(table)
    keep = np.ones(n, dtype=bool)
    if source in ("hvac", "weather") and n:
        per_day = rates.gaps_per_day if source == "hvac" else rates.weather_gaps_per_day
        t = _seconds(times)
        for _ in range(rng.poisson(per_day)):
            start = rng.uniform(t[0], t[-1])
            length = np.exp(rng.uniform(np.log(rates.gap_min_s), np.log(rates.gap_max_s)))
            keep &= ~((t >= start) & (t < start + length))
    if source == "trips" and n:
        keep &= rng.random(n) >= rates.missing_trip
    table = table.loc[keep].reset_index(drop=True)
    n = len(table)
    if source != "trips" and n:
        values = table.to_numpy(dtype=object)
        first_number = 2 if source == "hvac" else 1
        power = fmt.columns[source].get("p_hvac_kw")
        for j, name in enumerate(table.columns):
            if name == power:
                continue  # the meter's defects are its own (power_dropouts)
            if name in _temperature_columns(fmt, source):
                for i in np.flatnonzero(rng.random(n) < rates.spike_value):
                    values[i, j] = _spike(values[i, j], fmt, rng)
            if j >= first_number:
                values[rng.random(n) < rates.empty_value, j] = ""
        table = pd.DataFrame(values, columns=table.columns)
    rows = list(table.itertuples(index=False, name=None))
    if rows and rates.duplicate_row:
        dup = np.flatnonzero(rng.random(len(rows)) < rates.duplicate_row)
        for i in dup[::-1]:
            rows.insert(int(i) + 1, rows[int(i)])
    if len(rows) > 40 and rng.random() < rates.out_of_order_block:
        size = int(rng.integers(3, 20))
        i = int(rng.integers(0, len(rows) - size - 20))
        block = rows[i : i + size]
        del rows[i : i + size]
        j = int(rng.integers(i + 1, min(len(rows), i + 600)))
        rows[j:j] = block
    out = pd.DataFrame(rows, columns=table.columns)
    if len(out) and rng.random() < rates.garbage_line:
        i = int(rng.integers(len(out)))
        garbage = ["### logger restart ###"] + [""] * (len(out.columns) - 1)
        out = pd.concat(
            [out.iloc[:i], pd.DataFrame([garbage], columns=out.columns), out.iloc[i:]],
            ignore_index=True,
        )
    return out, bool(rng.random() < rates.unreadable_file)


def power_dropouts(
    table: pd.DataFrame,
    times: pd.DatetimeIndex,
    fmt: ExportFormat,
    rates: Defects,
    rng: np.random.Generator,
) -> pd.DataFrame:
    """The exported HVAC table with the power meter's dropouts: its field empty over spans of
    ``power_gap_min_s``…``power_gap_max_s`` (log-uniform), ``power_gaps_per_day`` a day."""
    column = fmt.columns["hvac"]["p_hvac_kw"]
    if not len(table) or column not in table:
        return table
    t = _seconds(times)
    lost = np.zeros(len(t), dtype=bool)
    for _ in range(rng.poisson(rates.power_gaps_per_day)):
        start = rng.uniform(t[0], t[-1])
        length = np.exp(rng.uniform(np.log(rates.power_gap_min_s), np.log(rates.power_gap_max_s)))
        lost |= (t >= start) & (t < start + length)
    table = table.copy()
    table.loc[lost, column] = ""
    return table


def _spike(text: str, fmt: ExportFormat, rng: np.random.Generator) -> str:
    """A sensor fault in place of a reading: a fault code (85.0 or −40.0) or a jump of 5–25 K."""
    kind = rng.integers(3)
    if kind == 2 and text:
        value = float(text.replace(fmt.decimal, ".")) + rng.choice([-1, 1]) * rng.uniform(5, 25)
    else:
        value = 85.0 if kind == 0 else -40.0
    return f"{value:.2f}".replace(".", fmt.decimal)


def _temperature_columns(fmt: ExportFormat, source: str) -> set[str]:
    names = {
        "hvac": ("t_room_up_c", "t_room_mid_c", "t_room_low_c", "t_ref_c"),
        "weather": ("t_amb_c",),
    }.get(source, ())
    return {fmt.columns[source][n] for n in names}
