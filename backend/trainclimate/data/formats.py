"""Raw fleet-log formats: the paper's three sources (Section III.A) as two campaigns export them.

Every source has a *canonical* table (the pipeline's input, whatever the origin — CSV files or the
service's stored telemetry):

- HVAC: ``time`` (UTC), ``mode`` (``regular`` / ``slumber`` / ``off``), ``t_ref_c``,
  ``t_room_up_c``, ``t_room_mid_c``, ``t_room_low_c`` (°C), ``speed_kmh``;
- weather: ``time``, ``latitude_deg``, ``longitude_deg``, ``t_amb_c``, ``ghi_w_m2``,
  ``solar_elevation_deg``, ``solar_azimuth_deg`` (clockwise from north);
- trips (train recordings, one row per trip): ``train``, ``departure``, ``arrival`` (UTC),
  ``origin``, ``destination``, ``occupancy_pct`` (% of seats).

Each campaign's export differs (:data:`FORMATS`): Winter/Spring 2022 files are semicolon-separated
with decimal commas, German column names and local Zurich time without offset; Summer 2023 files
are comma-separated ISO 8601 UTC with English names and the speed in m/s. :func:`read_source`
recognises a file's campaign and source from its header's column names, so files can be read in
any layout, and reads them as real exports come (encodings, separators, quotes, column order).

Files are named ``<campaign>/<source>/<train>_<coach>_<YYYY-MM-DD>.csv`` (:func:`log_path`).
"""

from __future__ import annotations

import codecs
import csv
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import charset_normalizer
import numpy as np
import pandas as pd

SOURCES = ("hvac", "weather", "trips")
CANONICAL = {
    "hvac": ("time", "mode", "t_ref_c", "t_room_up_c", "t_room_mid_c", "t_room_low_c", "speed_kmh"),
    "weather": (
        "time", "latitude_deg", "longitude_deg", "t_amb_c", "ghi_w_m2",
        "solar_elevation_deg", "solar_azimuth_deg",
    ),
    "trips": ("train", "departure", "arrival", "origin", "destination", "occupancy_pct"),
}  # fmt: skip
#: Columns holding times, and columns holding free text, per source (the rest are numbers).
TIME_COLUMNS = {"hvac": ("time",), "weather": ("time",), "trips": ("departure", "arrival")}
TEXT_COLUMNS = {"hvac": ("mode",), "weather": (), "trips": ("train", "origin", "destination")}
MODES = ("regular", "slumber", "off")


class FormatError(ValueError):
    """A file that is not a fleet log of a known format."""


@dataclass(frozen=True)
class ExportFormat:
    """How one campaign's export writes the canonical tables.

    ``columns[source]`` maps canonical names to the export's; ``time_format`` is a strftime
    pattern read in ``timezone``; numbers use ``decimal``; ``modes`` maps canonical mode names to
    the export's labels; the exported speed is ``speed_kmh * speed_factor``.
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
            {s: tuple(self.columns[s][c] for c in CANONICAL[s]) for s in SOURCES},
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


# --- reading ---------------------------------------------------------------------------------
#: The field separators an export may use (a spreadsheet's CSV export follows its locale).
DELIMITERS = (";", ",", "\t")
#: What a file that is not UTF-8 is read as: the Windows and ISO code pages of Western Europe.
LEGACY_ENCODINGS = ("cp1252", "latin_1")


@dataclass
class SourceTable:
    """A raw file read into its canonical table, with what reading had to drop and how the file
    was written: ``encoding``, ``delimiter``, the ``extra_columns`` it has besides the source's
    (ignored) and ``rows_read`` (its non-blank lines after the header)."""

    source: str
    campaign: str
    frame: pd.DataFrame
    dropped: Counter = field(default_factory=Counter)
    encoding: str = "utf-8"
    delimiter: str = ","
    extra_columns: tuple[str, ...] = ()
    rows_read: int = 0


def decode(data: bytes) -> tuple[str, str]:
    """A file's text and its encoding: UTF-8 (with or without a byte-order mark), else what
    charset-normalizer finds among :data:`LEGACY_ENCODINGS` (Excel on a Swiss or German Windows
    writes Windows-1252). Raises :class:`FormatError` for bytes that are none of them."""
    if data.startswith(codecs.BOM_UTF8):
        return data[len(codecs.BOM_UTF8) :].decode("utf-8"), "utf-8-sig"
    try:
        return data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        pass
    best = charset_normalizer.from_bytes(data, cp_isolation=list(LEGACY_ENCODINGS)).best()
    if best is None:
        raise FormatError("not text: neither UTF-8 nor Windows-1252")
    return str(best), best.encoding


def _fields(line: str, delimiter: str) -> list[str]:
    """One line's fields, quotes honoured within the line (a stray quote cannot swallow the
    lines after it) and surrounding blanks stripped."""
    return [f.strip() for f in next(csv.reader([line], delimiter=delimiter))]


@dataclass(frozen=True)
class _Layout:
    fmt: ExportFormat
    source: str
    delimiter: str
    names: tuple[str, ...]  # the header's column names, a trailing empty one dropped

    def position(self, col: str) -> int:
        """Where canonical column ``col`` is in the file."""
        return self.names.index(self.fmt.columns[self.source][col])

    @property
    def extra(self) -> tuple[str, ...]:
        return tuple(n for n in self.names if n not in self.fmt.header[self.source])


def _detect(header_line: str) -> _Layout:
    """The format, source and delimiter whose column names the header holds, in any order, with
    any other columns besides (a trailing separator's empty name dropped)."""
    for delimiter in DELIMITERS:
        names = _fields(header_line, delimiter)
        while names and names[-1] == "":
            names.pop()
        if len(set(names)) != len(names):
            continue
        for fmt in FORMATS.values():
            for source in SOURCES:
                if set(fmt.header[source]) <= set(names):
                    return _Layout(fmt, source, delimiter, tuple(names))
    raise FormatError(f"unrecognised header {header_line.strip()!r}")


#: An ISO 8601 time that carries its zone: ``Z`` or an offset.
_ZONED = re.compile(r"(?:Z|[+-]\d{2}:?\d{2})$")
#: The start of an ISO 8601 date and time.
_ISO_TIME = re.compile(r"\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}")


class TimezoneError(FormatError):
    """Times without a zone in a format whose times carry one, and no zone given."""


def _localize(naive: pd.DatetimeIndex, zone: str) -> pd.DatetimeIndex:
    """Wall times in ``zone`` → UTC. A wall time the autumn change repeats is resolved by order:
    its first occurrence in the file is summer time, a later one winter time; one the spring
    change skips → NaT."""
    ambiguous = np.zeros(len(naive), dtype=bool)
    try:
        return naive.tz_localize(zone, nonexistent="NaT", ambiguous="raise").tz_convert("UTC")
    except ValueError:  # a wall time the autumn change repeats
        pass
    seen: set = set()
    for i, t in enumerate(naive):
        if t is pd.NaT:
            continue
        ambiguous[i] = t not in seen  # the first time this wall time is read: summer time
        seen.add(t)
    return naive.tz_localize(zone, nonexistent="NaT", ambiguous=ambiguous).tz_convert("UTC")


def _parse_times(text: pd.Series, fmt: ExportFormat, timezone: str | None) -> pd.DatetimeIndex:
    """Export times → UTC, with or without seconds; unparseable times or ones the spring change
    skips → NaT. Times without a zone are read in ``timezone``, else in the campaign's
    documented zone when its export writes local times (winter-spring: Europe/Zurich), else
    :class:`TimezoneError`."""
    if fmt.time_format.startswith("%Y-%m-%dT"):
        # ISO 8601: pandas' ISO parser is an order of magnitude faster than strptime
        times = pd.to_datetime(text, format="ISO8601", errors="coerce", utc=True)
        unzoned = text.str.match(_ISO_TIME) & ~text.str.contains(_ZONED)
        if not unzoned.any():
            return pd.DatetimeIndex(times)  # (text that is no time at all: NaT, unparseable)
        if timezone is None:
            example = text[unzoned].iloc[0]
            raise TimezoneError(
                f"times without a time zone (e.g. {example!r}) in the {fmt.name} export, whose "
                "times are UTC with a Z: give their zone (--timezone, e.g. Europe/Zurich or UTC)"
            )
        naive = pd.to_datetime(text[unzoned], format="ISO8601", errors="coerce")
        times[unzoned] = _localize(pd.DatetimeIndex(naive), timezone).as_unit(times.dt.unit)
        return pd.DatetimeIndex(times)
    index = pd.to_datetime(text, format=fmt.time_format, errors="coerce")
    if index.isna().any():  # a spreadsheet saves times without their seconds
        minutes = fmt.time_format.replace(":%S", "")
        other = pd.to_datetime(text, format=minutes, errors="coerce")
        # (in the unit a time with seconds is read in, whichever way each was written)
        unit = pd.to_datetime(pd.Series(["2000-01-01 00:00:00"])).dt.unit
        index = index.astype(f"datetime64[{unit}]").fillna(other.astype(f"datetime64[{unit}]"))
    index = pd.DatetimeIndex(index)
    zone = timezone or fmt.timezone
    return index.tz_localize("UTC") if zone == "UTC" else _localize(index, zone)


def read_source(path: str | Path, timezone: str | None = None) -> SourceTable:
    """Read one raw log file of either campaign into its canonical table.

    The file may be written as real exports are (see ``docs/data.md``): UTF-8 with or without a
    byte-order mark or Windows-1252 (:func:`decode`), fields separated by semicolons, commas or
    tabs and quoted or not, a trailing separator, the source's columns by name in any order with
    others besides (ignored, and named in ``extra_columns``), numbers with a decimal point or
    comma, times with or without seconds. Times without a zone are read in ``timezone`` (an IANA
    name), by default in the campaign's (winter-spring: Europe/Zurich local time); a summer file
    whose times lack their ``Z`` needs ``timezone`` (:class:`TimezoneError` otherwise). The hour
    the autumn change repeats is resolved by order (first summer, then winter time).

    Rows that cannot be parsed — the wrong number of fields, an unreadable time or number, an
    unknown mode label — are dropped and counted as ``unparseable``; empty fields become NaN for
    the pipeline to judge. Raises :class:`FormatError` (or OSError) for a file that is not a
    fleet log at all.
    """
    path = Path(path)
    text, encoding = decode(path.read_bytes())
    # the non-blank lines as the CSV parser splits them (\n, \r\n or \r)
    lines = [line for line in re.split(r"\r\n?|\n", text) if line.strip()]
    if not lines:
        raise FormatError("empty file")
    layout = _detect(lines[0])
    fmt, source, width = layout.fmt, layout.source, len(layout.names)
    rows = []
    for line in lines[1:]:
        fields = _fields(line, layout.delimiter)
        while len(fields) > width and fields[-1] == "":  # a trailing separator
            fields.pop()
        if len(fields) == width:
            rows.append(fields)
    dropped = Counter(unparseable=len(lines) - 1 - len(rows))
    raw = pd.DataFrame(rows, columns=list(layout.names), dtype=object)

    out: dict[str, object] = {}
    ok = np.ones(len(raw), dtype=bool)
    for col in CANONICAL[source]:
        values = raw.iloc[:, layout.position(col)].astype(str)
        if col in TIME_COLUMNS[source]:
            times = _parse_times(values, fmt, timezone)
            ok &= ~times.isna()
            out[col] = times
        elif col == "mode":
            labels = {v: k for k, v in fmt.modes.items()}
            mode = values.map(labels)
            ok &= ~(mode.isna() & (values != "")).to_numpy()
            out[col] = mode.to_numpy(dtype=object)
        elif col in TEXT_COLUMNS[source]:
            out[col] = values.to_numpy(dtype=object)
        else:
            # a comma in a number field is a decimal comma, whatever the campaign
            values = values.str.replace(",", ".", regex=False)
            num = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
            ok &= ~(np.isnan(num) & (values != "").to_numpy())
            out[col] = num / fmt.speed_factor if col == "speed_kmh" else num
    frame = pd.DataFrame(out, index=raw.index).loc[ok]
    dropped["unparseable"] += int((~ok).sum())
    return SourceTable(
        source,
        fmt.name,
        frame.reset_index(drop=True),
        +dropped,
        encoding=encoding,
        delimiter=layout.delimiter,
        extra_columns=layout.extra,
        rows_read=len(lines) - 1,
    )
