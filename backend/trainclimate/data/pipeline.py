"""The data pipeline of the paper's Section III.A: raw fleet logs → clean trajectories.

For each coach and day (bounded memory, whatever the fleet's size):

0. **Clean** each source's canonical table (:func:`clean`): sort rows back into time order
   (repaired ``out_of_order``) and drop duplicated times (``duplicate``; a repeated time with
   other values is a ``conflicting_duplicate``, the first row in the file kept). A faulty *cell*
   invalidates that signal, not the row: it becomes NaN and is counted by column, as
   ``out_of_range`` (physically impossible) or ``spike`` (more than ``spike_k`` from the rolling
   median of its ``spike_window_min`` neighbourhood, widened to five samples for slow logs);
   small sensor offsets below zero are clipped (repaired ``clipped_offset``). A row left with no
   valid signal at all is dropped (``no_valid_value``), as is a trip that ends before it starts
   (``out_of_range``).
1. **Fuse** the three sources into one table at the HVAC's timestamps (:func:`fuse`): each
   weather signal is interpolated in time from its own valid samples (never across a gap longer
   than ``max_weather_gap_min``), the heading θ comes from the train's successive positions, the
   solar projections are ``Q_Gt = |G cos z|`` and ``Q_Gs = |G sin z sin(β − θ)|`` with z the
   solar *zenith* angle (90° − the logged elevation; see docs/model.md), and the occupancy P is
   the trip's. A moving train with no trip recorded has an unknown occupancy.
2. **Aggregate** to 1 min (:func:`aggregate`): y is the mean of the valid samples measured in the
   minute up to t, u and d the means of the valid samples over the minute from t (a missing
   value is left out, never counted as zero); a minute is in regular mode only if every sample
   in it is known to be. The metered HVAC power, where logged, and the share of the minute the
   train stood are carried along as u and d are (their means over the minute from t), but a
   minute without them is still complete.
3. **Segment and filter** (:func:`segment`): interior gaps of at most ``max_fill_min`` minutes
   between regular-mode minutes are interpolated — only the values missing there; a reading in
   the gap is kept (repaired ``short_gap``); every other incomplete or non-regular minute ends a
   trajectory; trajectories shorter than ``min_minutes`` are dropped.
4. **Down-sample** to 5 and 10 min (:func:`downsample`), blocks aligned to the clock: y at the
   block's start, u and d the block's means (the convention of
   :mod:`trainclimate.data.trajectory`); trajectories with fewer than ``min_points`` samples are
   dropped.

The input of steps 0–4 is a table of records per source, so the service's stored telemetry
feeds it as well as CSV files (:func:`trainclimate.data.dataset.build_dataset` reads the files).
"""

from __future__ import annotations

import logging
from collections import Counter, defaultdict
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from trainclimate.data.formats import CANONICAL, TEXT_COLUMNS, TIME_COLUMNS
from trainclimate.data.trajectory import D_NAMES, U_NAMES, Y_NAMES, Trajectory
from trainclimate.sim.routes import heading_from_positions
from trainclimate.sim.solar import roof_irradiance, side_irradiance

log = logging.getLogger(__name__)

SIGNALS = (*Y_NAMES, *U_NAMES, *D_NAMES)
#: The HVAC's metered electrical power: carried through to the trajectories beside y, u and d,
#: but not a signal a trajectory needs (a minute without it is still a complete minute).
POWER = "p_hvac_kw"
#: The share of each minute the train stood (speed below :data:`STANDING_KMH`), from the HVAC
#: log's speed samples: carried like the power (a 2-s log knows a 40-s stop inside a minute
#: whose mean speed is 30 km/h; the doors open then).
STANDING = "standing_share"
#: Below this speed a train stands. [km/h]
STANDING_KMH = 1.0
#: What the pipeline carries beside y, u and d into the trajectories, not required.
CARRIED = (POWER, STANDING)
#: Physically possible range of each canonical column (outside: a faulty reading).
RANGES = {
    "t_room_up_c": (-30.0, 60.0),
    "t_room_mid_c": (-30.0, 60.0),
    "t_room_low_c": (-30.0, 60.0),
    "t_ref_c": (10.0, 35.0),
    "speed_kmh": (0.0, 250.0),
    "latitude_deg": (-90.0, 90.0),
    "longitude_deg": (-180.0, 180.0),
    "t_amb_c": (-40.0, 50.0),
    "ghi_w_m2": (0.0, 1500.0),
    "solar_elevation_deg": (-90.0, 90.0),
    "solar_azimuth_deg": (0.0, 360.0),
    "occupancy_pct": (0.0, 300.0),
    "p_hvac_kw": (0.0, 200.0),
}
SPIKE_COLUMNS = {"hvac": ("t_ref_c", *Y_NAMES), "weather": ("t_amb_c",), "trips": ()}
#: Sensor offsets tolerated below a range's lower bound of 0 and read as 0 (counted as repaired
#: ``clipped_offset``): a pyranometer's night offset (down to −5 W/m²) and a standing train's
#: speed (down to −0.5 km/h). Beyond them a value is out of range.
OFFSET_TOLERANCE = {"ghi_w_m2": 5.0, "speed_kmh": 0.5}


class PipelineError(ValueError):
    """The input holds no usable data at all."""


@dataclass(frozen=True)
class PipelineSettings:
    """Knobs of the pipeline (defaults documented in the module docstring)."""

    sampling_min: tuple[int, ...] = (1, 5, 10)
    min_minutes: int = 30
    min_points: int = 6
    max_fill_min: int = 2
    max_weather_gap_min: float = 30.0
    spike_k: float = 4.0
    spike_window_min: float = 5.0


@dataclass
class Counts:
    """Rows (or minutes, where the reason says so) dropped and repaired, by reason; and per
    source (``hvac``, ``weather``, ``trips``; ``unknown`` for a file of no known source) the
    rows ``read``, ``kept`` (fused into the minutes) and dropped by reason, so that
    ``read == kept + sum(dropped)`` (:meth:`rows`), and the cells of kept rows invalidated, by
    column and reason (``cells``)."""

    dropped: Counter = field(default_factory=Counter)
    repaired: Counter = field(default_factory=Counter)
    read: Counter = field(default_factory=Counter)
    kept: Counter = field(default_factory=Counter)
    by_source: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))
    cells: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))

    def drop(self, source: str, reason: str, n: int) -> None:
        """``n`` rows of ``source`` dropped for ``reason``."""
        self.dropped[reason] += n
        self.by_source[source][reason] += n

    def invalidate(self, source: str, column: str, reason: str, n: int) -> None:
        """``n`` cells of ``source``'s ``column`` invalidated (made NaN) for ``reason``."""
        if n:
            self.cells[source][(column, reason)] += n

    def update(self, other: Counts) -> None:
        """Add ``other``'s counts to these."""
        self.dropped.update(other.dropped)
        self.repaired.update(other.repaired)
        self.read.update(other.read)
        self.kept.update(other.kept)
        for source, reasons in other.by_source.items():
            self.by_source[source].update(reasons)
        for source, cells in other.cells.items():
            self.cells[source].update(cells)

    def invalid_cells(self) -> dict[str, int]:
        """Cells invalidated, by reason, over every source and column."""
        total: Counter = Counter()
        for cells in self.cells.values():
            for (_, reason), n in cells.items():
                total[reason] += n
        return {k: int(v) for k, v in sorted(total.items()) if v}

    def rows(self) -> dict[str, dict]:
        """Per source: ``read``, ``kept`` and ``dropped`` (reason → rows, those not zero), and
        ``invalid_cells`` (column → reason → cells)."""
        sources = sorted({*self.read, *self.kept, *self.by_source})
        return {
            s: {
                "read": int(self.read[s]),
                "kept": int(self.kept[s]),
                "dropped": {k: int(v) for k, v in sorted(self.by_source[s].items()) if v},
                "invalid_cells": by_column(self.cells[s]),
            }
            for s in sources
        }


def by_column(cells: Counter) -> dict[str, dict[str, int]]:
    """Cell counts keyed by (column, reason) as column → reason → count, zeros left out."""
    out: dict[str, dict[str, int]] = defaultdict(dict)
    for (column, reason), n in sorted(cells.items()):
        if n:
            out[column][reason] = int(n)
    return dict(out)


def _seconds(times) -> np.ndarray:
    return pd.DatetimeIndex(times).as_unit("ns").asi8 / 1e9


# --- 0. clean ----------------------------------------------------------------------------------
def clean(frame: pd.DataFrame, source: str, counts: Counts, settings: PipelineSettings):
    """One source's canonical table, sorted, de-duplicated, its faulty cells NaN (see module).

    Cells already NaN (empty or unreadable in the file: counted by the reader) are not counted
    again.
    """
    key = "departure" if source == "trips" else "time"
    frame = frame.reset_index(drop=True)
    t = _seconds(frame[key]) if len(frame) else np.array([])
    if len(t):
        late = t < np.maximum.accumulate(np.concatenate([[-np.inf], t[:-1]]))
        counts.repaired["out_of_order"] += int(late.sum())
        frame = frame.iloc[np.argsort(t, kind="stable")].reset_index(drop=True)
    dup = frame.duplicated(subset=[key], keep="first")
    # a repeated time with other values conflicts: the first row in the file is kept (the rule),
    # and the first conflict is shown
    conflict = dup & ~frame.duplicated(keep="first")
    if conflict.any():
        first = frame.loc[conflict].iloc[0]
        kept = frame.loc[(frame[key] == first[key]) & ~dup].iloc[0]
        log.warning(
            "%s: %d row(s) repeat a time with other values; the first in the file is kept, "
            "e.g. at %s kept %s, dropped %s",
            source,
            int(conflict.sum()),
            first[key],
            kept.drop(key).to_dict(),
            first.drop(key).to_dict(),
        )
    counts.drop(source, "duplicate", int((dup & ~conflict).sum()))
    counts.drop(source, "conflicting_duplicate", int(conflict.sum()))
    frame = frame.loc[~dup]

    frame = frame.copy()
    for col, tolerance in OFFSET_TOLERANCE.items():
        if col in frame:
            v = frame[col].to_numpy(dtype=float)
            offset = (v < 0.0) & (v >= -tolerance)
            counts.repaired["clipped_offset"] += int(offset.sum())
            frame.loc[offset, col] = 0.0
    # (an optional column may be absent: a table from elsewhere than the reader)
    present = [c for c in CANONICAL[source] if c in frame]
    for col in present:
        if col in RANGES:
            lo, hi = RANGES[col]
            v = frame[col].to_numpy(dtype=float)
            bad = (v < lo) | (v > hi)
            counts.invalidate(source, col, "out_of_range", int(bad.sum()))
            frame.loc[bad, col] = np.nan
    if source == "trips":
        backwards = (frame["arrival"] <= frame["departure"]).to_numpy()
        counts.drop(source, "out_of_range", int(backwards.sum()))
        frame = frame.loc[~backwards]

    if SPIKE_COLUMNS[source] and len(frame):
        indexed = frame.set_index(key)
        # at least two samples either side: the winter weather comes every 10 min, and a 5-min
        # window would hold each reading alone, so no spike could ever be found there
        ts = _seconds(indexed.index)
        period = float(np.median(np.diff(ts))) if len(ts) > 1 else 0.0
        window = pd.Timedelta(seconds=max(settings.spike_window_min * 60.0, 5.0 * period))
        for col in SPIKE_COLUMNS[source]:
            median = indexed[col].rolling(window, center=True, min_periods=1).median()
            spike = (np.abs(indexed[col] - median) > settings.spike_k).to_numpy()
            counts.invalidate(source, col, "spike", int(spike.sum()))
            frame.loc[spike, col] = np.nan

    signals = [c for c in present if c not in (*TIME_COLUMNS[source], *TEXT_COLUMNS[source])]
    if source == "hvac":
        signals.append("mode")
    if source != "trips":  # a trip's times are data: its train is on it, occupancy known or not
        empty = frame[signals].isna().all(axis=1).to_numpy()
        counts.drop(source, "no_valid_value", int(empty.sum()))
        frame = frame.loc[~empty]
    return frame.reset_index(drop=True)


# --- 1. fuse -----------------------------------------------------------------------------------
def _interpolate(times_s, sample_s, values, max_gap_s, hold_s):
    """Linear interpolation of ``values`` sampled at ``sample_s`` onto ``times_s``; NaN between
    samples more than ``max_gap_s`` apart and beyond ``hold_s`` outside the samples."""
    out = np.interp(times_s, sample_s, values)
    i = np.searchsorted(sample_s, times_s, side="right")
    inside = (i > 0) & (i < len(sample_s))
    gap = np.full(len(times_s), np.inf)
    gap[inside] = sample_s[i[inside]] - sample_s[i[inside] - 1]
    exact = np.isin(times_s, sample_s)
    near_ends = ((times_s >= sample_s[0] - hold_s) & (times_s < sample_s[0])) | (
        (times_s > sample_s[-1]) & (times_s <= sample_s[-1] + hold_s)
    )
    ok = (inside & (gap <= max_gap_s)) | exact | near_ends
    return np.where(ok, out, np.nan)


def fuse(
    hvac: pd.DataFrame,
    weather: pd.DataFrame | None,
    trips: pd.DataFrame | None,
    settings: PipelineSettings,
    counts: Counts | None = None,
) -> pd.DataFrame:
    """Step 1: one table at the HVAC's times with ``mode``, u, y and d (see the module), and
    ``untracked``: the train moves with no trip recorded, or there is no trips log at all.

    ``weather`` or ``trips`` None (file missing or unreadable) leave the signals they give NaN;
    an empty ``trips`` table means no trip that day (occupancy 0 while standing).
    """
    counts = counts or Counts()
    out = pd.DataFrame({"time": hvac["time"].array, "mode": hvac["mode"].to_numpy()})
    for col in ("t_ref_c", *Y_NAMES, "speed_kmh", POWER):
        out[col] = hvac[col].to_numpy(dtype=float) if col in hvac else np.full(len(hvac), np.nan)
    ts = _seconds(out["time"])
    n = len(out)

    if weather is not None and len(weather) >= 2:
        ws = _seconds(weather["time"])
        period = float(np.median(np.diff(ws)))
        max_gap = settings.max_weather_gap_min * 60.0

        def interp(values: np.ndarray) -> np.ndarray:
            ok = np.isfinite(values)  # each signal from its own valid samples
            if ok.sum() < 2:
                return np.full(n, np.nan)
            return _interpolate(ts, ws[ok], values[ok], max_gap, period)

        azimuth = weather["solar_azimuth_deg"].to_numpy(float).copy()
        valid_az = np.isfinite(azimuth)
        azimuth[valid_az] = np.unwrap(azimuth[valid_az], period=360)
        ghi = interp(weather["ghi_w_m2"].to_numpy(float))
        zenith = 90.0 - interp(weather["solar_elevation_deg"].to_numpy(float))
        lat = weather["latitude_deg"].to_numpy(float)
        lon = weather["longitude_deg"].to_numpy(float)
        placed = np.isfinite(lat) & np.isfinite(lon)
        theta = np.full(n, np.nan)
        if placed.sum() >= 2:
            wp = ws[placed]
            heading = heading_from_positions(lat[placed], lon[placed])
            # the heading of the interval between positions a time falls in: its direction
            idx = np.clip(np.searchsorted(wp, ts, side="right") - 1, 0, len(wp) - 1)
            known = np.isfinite(_interpolate(ts, wp, np.zeros(len(wp)), max_gap, period))
            theta = np.where(known, heading[idx], np.nan)
        out["t_amb_c"] = interp(weather["t_amb_c"].to_numpy(float))
        out["q_gt_w_m2"] = roof_irradiance(ghi, zenith)
        out["q_gs_w_m2"] = side_irradiance(ghi, zenith, np.mod(interp(azimuth), 360.0), theta)
        unknown = np.isnan(ghi) | np.isnan(zenith)
        out.loc[unknown, "q_gt_w_m2"] = np.nan
        out.loc[unknown | np.isnan(theta) | np.isnan(out["q_gs_w_m2"]), "q_gs_w_m2"] = np.nan
    else:
        for col in ("t_amb_c", "q_gt_w_m2", "q_gs_w_m2"):
            out[col] = np.nan

    speed = out["speed_kmh"].to_numpy()
    if trips is None:
        out["occupancy_pct"] = np.nan
        out["untracked"] = True
    else:
        occ = np.zeros(n)
        on_trip = np.zeros(n, dtype=bool)
        if len(trips):
            dep, arr = _seconds(trips["departure"]), _seconds(trips["arrival"])
            j = np.searchsorted(dep, ts, side="right") - 1
            on_trip = (j >= 0) & (ts < arr[np.clip(j, 0, None)])
            occ = np.where(
                on_trip, trips["occupancy_pct"].to_numpy(float)[np.clip(j, 0, None)], 0.0
            )
        # off a trip, a standing train is empty; one moving, or of unknown speed, is unknown
        out["occupancy_pct"] = np.where(~on_trip & ~(speed <= 5.0), np.nan, occ)
        out["untracked"] = ~on_trip & (speed > 5.0)
    return out


# --- 2. aggregate ----------------------------------------------------------------------------
def aggregate(fused: pd.DataFrame, start: pd.Timestamp, end: pd.Timestamp) -> pd.DataFrame:
    """Step 2: the fused table as 1-min values on the full grid [start, end) (NaN: no data).

    The minute labelled t holds y measured *by* t — the mean of the room-temperature samples in
    (t − 1 min, t] — and the means of u and d over [t, t + 1 min), so y(t) never overlaps the
    interval of u(t) and d(t) (the convention of :mod:`trainclimate.data.trajectory`). Column
    ``regular`` is 1 for minutes [t, t + 1 min) entirely in regular mode, 0 otherwise, NaN
    without data or with a sample of unknown mode. Missing values are left out of the means.
    """
    frame = fused.drop(columns=["mode", "untracked"], errors="ignore").set_index("time")
    mode = fused["mode"].to_numpy(dtype=object)
    frame["regular"] = np.where(pd.isna(mode), np.nan, mode == "regular").astype(float)
    speed = frame["speed_kmh"].to_numpy(dtype=float)
    frame[STANDING] = np.where(np.isnan(speed), np.nan, speed < STANDING_KMH)
    grid = pd.date_range(start, end, freq="1min", inclusive="left")
    acting = [c for c in frame.columns if c not in Y_NAMES]
    minute = frame.index.floor("1min")
    means = frame[acting].groupby(minute).mean()  # (NaN left out, never counted as zero)
    # all samples regular → 1; one of unknown mode → NaN
    means["regular"] = np.floor(means["regular"])
    unknown = frame["regular"].isna().groupby(minute).any()
    means.loc[unknown.to_numpy(), "regular"] = np.nan
    measured = frame[list(Y_NAMES)].groupby(frame.index.ceil("1min")).mean()
    minutes = means.reindex(grid).join(measured.reindex(grid))
    return minutes.reindex(columns=[*SIGNALS, *CARRIED, "regular"])  # (no power logged: NaN)


# --- 3. segment ------------------------------------------------------------------------------
def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) index pairs of the runs of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def segment(
    minutes: pd.DataFrame, settings: PipelineSettings, counts: Counts
) -> list[pd.DataFrame]:
    """Step 3: the gap-free regular-mode pieces of a 1-min table, at least ``min_minutes`` long."""
    values = minutes[list(SIGNALS)].to_numpy(dtype=float)
    regular = minutes["regular"].to_numpy()
    complete = np.isfinite(values).all(axis=1)
    valid = complete & (regular == 1)
    # short interior gaps (missing data, not a known other mode) are interpolated
    fillable = ~valid & (regular != 0)
    for a, b in _runs(fillable):
        if (
            b - a <= settings.max_fill_min
            and a > 0
            and b < len(valid)
            and valid[a - 1]
            and valid[b]
        ):
            # only the missing values: a signal measured in the gap keeps its reading
            for j in range(values.shape[1]):
                missing = a + np.flatnonzero(~np.isfinite(values[a:b, j]))
                ends = [values[a - 1, j], values[b, j]]
                values[missing, j] = np.interp(missing, [a - 1, b], ends)
            valid[a:b] = True
            counts.repaired["short_gap_minutes"] += b - a
    filled = minutes.copy()
    filled[list(SIGNALS)] = values
    pieces = []
    for a, b in _runs(valid):
        if b - a >= settings.min_minutes:
            pieces.append(filled.iloc[a:b])
        else:
            counts.dropped["too_short_minutes"] += b - a
    return pieces


def piece_trajectory(frame: pd.DataFrame, meta: dict, sampling_min: int) -> Trajectory:
    """A down-sampled piece as a :class:`Trajectory` labelled with ``meta``."""
    return Trajectory(
        time=pd.DatetimeIndex(frame.index),
        y=frame[list(Y_NAMES)].to_numpy(float),
        u=frame[list(U_NAMES)].to_numpy(float),
        d=frame[list(D_NAMES)].to_numpy(float),
        p_kw=frame[POWER].to_numpy(float),
        standing=frame[STANDING].to_numpy(float),
        sampling_min=sampling_min,
        **meta,
    )


# --- 4. down-sample --------------------------------------------------------------------------
def downsample(piece: pd.DataFrame, step_min: int) -> pd.DataFrame:
    """Step 4: a 1-min piece as blocks of ``step_min`` aligned to the clock, each complete.

    y is the 1-min value at the block's start; u, d and the power the block's means (the
    power NaN if a minute of the block lacks it).
    """
    minute = _seconds(piece.index) // 60
    first = int(-(-minute[0] // step_min) * step_min)  # first aligned minute in the piece
    n_blocks = int((minute[-1] + 1 - first) // step_min)
    if n_blocks <= 0:
        return piece.iloc[:0]
    offset = int(first - minute[0])
    block = piece.iloc[offset : offset + n_blocks * step_min]
    cols = [*SIGNALS, *CARRIED]
    means = block[cols].to_numpy(float).reshape(n_blocks, step_min, -1).mean(axis=1)
    out = pd.DataFrame(means, columns=cols, index=block.index[::step_min])
    out[list(Y_NAMES)] = block[list(Y_NAMES)].to_numpy(float)[::step_min]
    return out


def process_coach_day(
    sources: dict[str, pd.DataFrame | None],
    *,
    start: pd.Timestamp,
    end: pd.Timestamp,
    meta: dict,
    settings: PipelineSettings | None = None,
) -> tuple[dict[int, list[Trajectory]], Counts]:
    """Steps 0–4 for one coach and day: canonical ``sources`` (``hvac``, ``weather``,
    ``trips``; a missing one None) covering [start, end) → trajectories by sampling time.

    ``meta`` holds ``campaign``, ``train`` and ``coach``.
    """
    settings = settings or PipelineSettings()
    counts = Counts()
    out: dict[int, list[Trajectory]] = {s: [] for s in settings.sampling_min}
    hvac = sources.get("hvac")
    if hvac is None or not len(hvac):
        for name, frame in sources.items():
            if frame is not None and name != "hvac":
                counts.drop(name, "no_hvac_log", len(frame))
        return out, counts
    cleaned = {
        name: None if frame is None else clean(frame, name, counts, settings)
        for name, frame in sources.items()
    }
    for name in ("weather", "trips"):
        if cleaned.get(name) is not None:
            counts.kept[name] += len(cleaned[name])
    fused = fuse(cleaned["hvac"], cleaned.get("weather"), cleaned.get("trips"), settings, counts)
    inside = ((fused["time"] >= start) & (fused["time"] < end)).to_numpy()
    # a row of a train moving with no trip recorded, or of a coach-day with no trips log at all,
    # cannot be used: its occupancy is unknown
    untracked = fused["untracked"].to_numpy(dtype=bool) & inside
    why = "no_trips_log" if cleaned.get("trips") is None else "moving_without_trip_rows"
    counts.drop("hvac", "outside_day_window", int((~inside).sum()))
    counts.drop("hvac", why, int(untracked.sum()))
    counts.kept["hvac"] += int((inside & ~untracked).sum())
    fused = fused[inside & ~untracked]
    if not len(fused):
        return out, counts
    pieces = segment(aggregate(fused, start, end), settings, counts)
    for piece in pieces:
        for step in settings.sampling_min:
            sampled = piece if step == 1 else downsample(piece, step)
            if step == 1 or len(sampled) >= settings.min_points:
                out[step].append(piece_trajectory(sampled, meta, step))
    return out, counts
