"""The :class:`Trajectory`: one continuous, gap-free piece of a coach's regular-mode operation.

This is what the predictors consume (paper, Section III.B): per sample k on a uniform grid

- ``y[k]`` = T_room of the decks up, mid, low (°C), shape (n, 3);
- ``u[k]`` = T_ref (°C), shape (n, 1);
- ``d[k]`` = [T_amb (°C), Q_Gt (W/m²), Q_Gs (W/m²), P (% of seats), V (km/h)], shape (n, 5);

and beside them ``p_kw[k]``, the HVAC's metered electrical power (kW, shape (n,); NaN where the
coach does not meter it), and ``standing[k]``, the share of the interval the train stood — data
for calibrating the simulator, not predictor inputs.

Sampling convention (the same at 1, 5 and 10 min, and the one the controller uses): ``time[k]`` is
the start of interval k. ``y[k]`` is the room temperature measured by ``time[k]`` (the mean of
the sensor samples in the minute before it); ``u[k]`` and ``d[k]`` are the setpoint applied and the
disturbance acting over ``[time[k], time[k+1])`` (their means over the interval), as is the
power ``p_kw[k]``. So y(k+1) depends
on u(k) and d(k), never on u(k+1) or d(k+1) — the causal structure of the Transient Predictor —
and y(k) is known when u(k) is chosen, as in the controller.

Trajectories of one sampling time are stored together in one Parquet file in long format (one
row per sample, ``traj_id`` naming the trajectory); :class:`TrajectoryWriter` appends them in row
groups so memory stays bounded, and :func:`read_trajectories` reads them back.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

Y_NAMES = ("t_room_up_c", "t_room_mid_c", "t_room_low_c")
U_NAMES = ("t_ref_c",)
D_NAMES = ("t_amb_c", "q_gt_w_m2", "q_gs_w_m2", "occupancy_pct", "speed_kmh")
#: Unit of every signal, by column name.
UNITS = {
    **dict.fromkeys(Y_NAMES, "degC"),
    "t_ref_c": "degC",
    "t_amb_c": "degC",
    "q_gt_w_m2": "W/m2",
    "q_gs_w_m2": "W/m2",
    "occupancy_pct": "% of seats",
    "speed_kmh": "km/h",
    "p_hvac_kw": "kW",
    "standing_share": "–",
}
META_NAMES = ("traj_id", "campaign", "train", "coach", "sampling_min")

_SCHEMA = pa.schema(
    [
        ("traj_id", pa.string()),
        ("campaign", pa.string()),
        ("train", pa.string()),
        ("coach", pa.string()),
        ("sampling_min", pa.int16()),
        ("time", pa.timestamp("us", tz="UTC")),
        *[
            (name, pa.float64())
            for name in (*Y_NAMES, *U_NAMES, *D_NAMES, "p_hvac_kw", "standing_share")
        ],
    ]
)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A uniformly sampled, gap-free trajectory (see the module docstring for the convention).

    ``time`` (n,) tz-aware UTC; ``y`` (n, 3), ``u`` (n, 1), ``d`` (n, 5) float arrays;
    ``campaign``, ``train``, ``coach`` where it comes from; ``sampling_min`` its step in minutes;
    ``p_kw`` (n,) the metered HVAC power in kW (None: not metered, stored as NaN);
    ``standing`` (n,) the share of each interval the train stood (None: unknown, NaN).
    """

    time: pd.DatetimeIndex
    y: np.ndarray
    u: np.ndarray
    d: np.ndarray
    campaign: str = ""
    train: str = ""
    coach: str = ""
    sampling_min: int = 1
    p_kw: np.ndarray | None = None
    standing: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.time)
        for name in ("p_kw", "standing"):
            given = getattr(self, name)
            value = np.full(n, np.nan) if given is None else np.asarray(given, dtype=float)
            if value.shape != (n,):
                raise ValueError(f"trajectory {name} must have shape ({n},)")
            object.__setattr__(self, name, value)
        for name, width in (("y", 3), ("u", 1), ("d", 5)):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (n, width):
                raise ValueError(f"trajectory {name} must have shape ({n}, {width})")
            object.__setattr__(self, name, value)
        if self.time.tz is None:
            raise ValueError("trajectory time must be timezone-aware")

    def __len__(self) -> int:
        return len(self.time)

    @property
    def id(self) -> str:
        """``campaign/coach/start`` (start as UTC ``YYYYmmddTHHMM``) — unique per sampling time."""
        return f"{self.campaign}/{self.coach}/{self.time[0].tz_convert('UTC'):%Y%m%dT%H%M}"

    def frame(self) -> pd.DataFrame:
        """The trajectory as a long-format table (the Parquet layout)."""
        n = len(self)
        cols: dict[str, object] = {
            "traj_id": [self.id] * n,
            "campaign": [self.campaign] * n,
            "train": [self.train] * n,
            "coach": [self.coach] * n,
            "sampling_min": np.full(n, self.sampling_min, dtype=np.int16),
            "time": self.time.tz_convert("UTC"),
        }
        for j, name in enumerate(Y_NAMES):
            cols[name] = self.y[:, j]
        cols["t_ref_c"] = self.u[:, 0]
        for j, name in enumerate(D_NAMES):
            cols[name] = self.d[:, j]
        cols["p_hvac_kw"] = self.p_kw
        cols["standing_share"] = self.standing
        return pd.DataFrame(cols)


def from_frame(frame: pd.DataFrame) -> Trajectory:
    """The :class:`Trajectory` of a long-format table holding one trajectory."""
    first = frame.iloc[0]
    return Trajectory(
        time=pd.DatetimeIndex(frame["time"]).tz_convert("UTC"),
        y=frame[list(Y_NAMES)].to_numpy(dtype=float),
        u=frame[list(U_NAMES)].to_numpy(dtype=float),
        d=frame[list(D_NAMES)].to_numpy(dtype=float),
        campaign=str(first["campaign"]),
        train=str(first["train"]),
        coach=str(first["coach"]),
        sampling_min=int(first["sampling_min"]),
        # (a file written before these were carried has no such columns)
        p_kw=frame["p_hvac_kw"].to_numpy(dtype=float) if "p_hvac_kw" in frame else None,
        standing=(
            frame["standing_share"].to_numpy(dtype=float) if "standing_share" in frame else None
        ),
    )


class TrajectoryWriter:
    """Appends trajectories to one Parquet file, a row group per :meth:`write` call.

    Use as a context manager. Files written from the same trajectories in the same order are
    byte-identical.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = pq.ParquetWriter(self.path, _SCHEMA, compression="zstd")
        self.count = 0
        self.points = 0

    def write(self, trajectories: Iterable[Trajectory]) -> None:
        """Append trajectories to the Parquet file."""
        frames = [t.frame() for t in trajectories]
        if not frames:
            return
        table = pa.Table.from_pandas(
            pd.concat(frames, ignore_index=True), schema=_SCHEMA, preserve_index=False
        )
        self._writer.write_table(table)
        self.count += len(frames)
        self.points += table.num_rows

    def close(self) -> None:
        """Finish the Parquet file (also when nothing was written)."""
        self._writer.close()

    def __enter__(self) -> TrajectoryWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def iter_trajectories(path: str | Path, filters=None) -> Iterator[Trajectory]:
    """Yield the trajectories of a Parquet file row group by row group (bounded memory).

    ``filters``: optional predicate ``(campaign, coach) -> bool`` choosing which to yield.
    """
    parquet = pq.ParquetFile(path)
    for g in range(parquet.num_row_groups):
        frame = parquet.read_row_group(g).to_pandas()
        for _, part in frame.groupby("traj_id", sort=False):
            first = part.iloc[0]
            if filters is None or filters(str(first["campaign"]), str(first["coach"])):
                yield from_frame(part)


def read_trajectories(path: str | Path, filters=None) -> list[Trajectory]:
    """All trajectories of a Parquet file written by :class:`TrajectoryWriter`."""
    return list(iter_trajectories(path, filters))
