"""Raw fleet-log formats: the paper's three sources (Section III.A) as two campaigns export them.

Every source has a *canonical* table (the pipeline's input, whatever the origin — CSV files or the
service's stored telemetry):

- HVAC: ``time`` (UTC), ``mode`` (``regular`` / ``slumber`` / ``off``), ``t_ref_c``,
  ``t_room_up_c``, ``t_room_mid_c``, ``t_room_low_c`` (°C), ``speed_kmh`` and, where the coach
  meters it, ``p_hvac_kw``: the climate system's electrical power, the mean over the sample's
  interval [t, t + period) (kW; an optional column, NaN in a file without it);
- weather: ``time``, ``latitude_deg``, ``longitude_deg``, ``t_amb_c``, ``ghi_w_m2``,
  ``solar_elevation_deg``, ``solar_azimuth_deg`` (clockwise from north);
- trips (train recordings, one row per trip): ``train``, ``departure``, ``arrival`` (UTC),
  ``origin``, ``destination``, ``occupancy_pct`` (% of seats).

Each campaign's export differs (:data:`FORMATS`): Winter/Spring 2022 files are semicolon-separated
with decimal commas, German column names and local Zurich time without offset; Summer 2023 files
are comma-separated ISO 8601 UTC with English names and the speed in m/s. :func:`read_source`
recognises a file's campaign and source from its header's column names, so files can be read in
any layout, as real exports come (:mod:`trainclimate.data.reader`).

Files are named ``<campaign>/<source>/<train>_<coach>_<YYYY-MM-DD>.csv`` (:func:`log_path`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

SOURCES = ("hvac", "weather", "trips")
CANONICAL = {
    "hvac": (
        "time", "mode", "t_ref_c", "t_room_up_c", "t_room_mid_c", "t_room_low_c", "speed_kmh",
        "p_hvac_kw",
    ),
    "weather": (
        "time", "latitude_deg", "longitude_deg", "t_amb_c", "ghi_w_m2",
        "solar_elevation_deg", "solar_azimuth_deg",
    ),
    "trips": ("train", "departure", "arrival", "origin", "destination", "occupancy_pct"),
}  # fmt: skip
#: Columns holding times, and columns holding free text, per source (the rest are numbers).
TIME_COLUMNS = {"hvac": ("time",), "weather": ("time",), "trips": ("departure", "arrival")}
TEXT_COLUMNS = {"hvac": ("mode",), "weather": (), "trips": ("train", "origin", "destination")}
#: Columns a file may lack (read as NaN): what not every coach meters.
OPTIONAL_COLUMNS = {"hvac": ("p_hvac_kw",), "weather": (), "trips": ()}
MODES = ("regular", "slumber", "off")


class FormatError(ValueError):
    """A file that is not a fleet log of a known format."""


@dataclass(frozen=True)
class ExportFormat:
    """How one campaign's export writes the canonical tables.

    ``columns[source]`` maps canonical names to the export's; ``time_format`` is a strftime
    pattern read in ``timezone``; numbers use ``decimal``; ``modes`` maps canonical mode names to
    the export's labels; the exported speed is ``speed_kmh * speed_factor``. ``header[source]``
    holds the column names every file of the source has (the optional ones left out).
    """

    name: str
    sep: str
    decimal: str
    time_format: str
    timezone: str
    columns: dict[str, dict[str, str]]
    modes: dict[str, str]
    speed_factor: float = 1.0
    header: dict[str, tuple[str, ...]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "header",
            {
                s: tuple(self.columns[s][c] for c in CANONICAL[s] if c not in OPTIONAL_COLUMNS[s])
                for s in SOURCES
            },
        )


WINTER_FORMAT = ExportFormat(
    name="winter-spring",
    sep=";",
    decimal=",",
    time_format="%d.%m.%Y %H:%M:%S",
    timezone="Europe/Zurich",
    columns={
        "hvac": dict(
            time="Zeit", mode="Betriebsart", t_ref_c="T_Soll", t_room_up_c="T_Raum_OG",
            t_room_mid_c="T_Raum_MG", t_room_low_c="T_Raum_UG", speed_kmh="Geschwindigkeit_kmh",
            p_hvac_kw="P_Klima_kW",
        ),
        "weather": dict(
            time="Zeit", latitude_deg="Breite", longitude_deg="Laenge", t_amb_c="T_aussen",
            ghi_w_m2="Globalstrahlung", solar_elevation_deg="Sonnenhoehe",
            solar_azimuth_deg="Sonnenazimut",
        ),
        "trips": dict(
            train="Zug", departure="Abfahrt", arrival="Ankunft", origin="Von",
            destination="Nach", occupancy_pct="Belegung_Prozent",
        ),
    },
    modes={"regular": "Normal", "slumber": "Schlummer", "off": "Aus"},
)  # fmt: skip

SUMMER_FORMAT = ExportFormat(
    name="summer",
    sep=",",
    decimal=".",
    time_format="%Y-%m-%dT%H:%M:%SZ",
    timezone="UTC",
    columns={
        "hvac": dict(
            time="timestamp", mode="hvac_mode", t_ref_c="t_setpoint", t_room_up_c="t_room_upper",
            t_room_mid_c="t_room_middle", t_room_low_c="t_room_lower", speed_kmh="speed_mps",
            p_hvac_kw="p_hvac_kw",
        ),
        "weather": dict(
            time="timestamp", latitude_deg="lat", longitude_deg="lon", t_amb_c="temp_air",
            ghi_w_m2="ghi", solar_elevation_deg="sun_elevation", solar_azimuth_deg="sun_azimuth",
        ),
        "trips": dict(
            train="train", departure="departure", arrival="arrival", origin="from",
            destination="to", occupancy_pct="occupancy_pct",
        ),
    },
    modes={"regular": "REGULAR", "slumber": "SLUMBER", "off": "OFF"},
    speed_factor=1 / 3.6,
)  # fmt: skip

FORMATS = {f.name: f for f in (WINTER_FORMAT, SUMMER_FORMAT)}

_NAME = re.compile(
    r"^(?P<train>[^_]+)_(?P<coach>[^_]+)_(?P<day>\d{4}-\d{2}-\d{2})\.csv$", re.IGNORECASE
)


def log_path(root: Path, campaign: str, source: str, train: str, coach: str, day: str) -> Path:
    """Where a raw log file lives: ``root/campaign/source/train_coach_day.csv``."""
    return Path(root) / campaign / source / f"{train}_{coach}_{day}.csv"


def parse_log_name(path: Path) -> tuple[str, str, str] | None:
    """(train, coach, day) from a log file's name, or None if it does not follow the layout."""
    m = _NAME.match(Path(path).name)
    return (m["train"], m["coach"], m["day"]) if m else None


# --- writing ---------------------------------------------------------------------------------
def _format_number(values: pd.Series, decimal: str, digits: int) -> list[str]:
    return [
        "" if np.isnan(v) else f"{v:.{digits}f}".replace(".", decimal)
        for v in np.asarray(values, dtype=float)
    ]


def to_export(frame: pd.DataFrame, source: str, fmt: ExportFormat) -> pd.DataFrame:
    """A canonical table converted to ``fmt``'s columns and text (all values as strings)."""
    out = {}
    for col in CANONICAL[source]:
        if col not in frame and col in OPTIONAL_COLUMNS[source]:
            continue
        values = frame[col]
        if col in TIME_COLUMNS[source]:
            text = pd.DatetimeIndex(values).tz_convert(fmt.timezone).strftime(fmt.time_format)
            out[fmt.columns[source][col]] = np.asarray(text, dtype=object)
        elif col == "mode":
            out[fmt.columns[source][col]] = values.map(fmt.modes).fillna("").to_numpy()
        elif col in TEXT_COLUMNS[source]:
            out[fmt.columns[source][col]] = values.astype(str).to_numpy()
        else:
            v = values.astype(float) * (fmt.speed_factor if col == "speed_kmh" else 1.0)
            digits = 6 if col in ("latitude_deg", "longitude_deg") else 2
            out[fmt.columns[source][col]] = _format_number(v, fmt.decimal, digits)
    return pd.DataFrame(out)


def write_export(frame: pd.DataFrame, path: Path, fmt: ExportFormat) -> None:
    """Write an already exported table (:func:`to_export`, possibly with defects added)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, sep=fmt.sep, index=False, lineterminator="\n")
