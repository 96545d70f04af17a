"""Reading raw fleet-log files as real exports write them, block by block, into canonical tables.

A file may be written the ways spreadsheets and loggers' export tools write it (``docs/data.md``
shows each): UTF-8 with or without a byte-order mark or Windows-1252, fields separated by
semicolons, commas or tabs, quoted or not, a trailing separator, the source's columns by name in
any order with others besides, numbers with a decimal point or comma, times with or without
seconds. The file is read :data:`BLOCK_BYTES` at a time and only the canonical columns of the
rows inside the window asked for are kept, so memory follows the day read, not the file's size.

What reading cannot use is counted, never dropped silently: a *row* goes when it cannot be placed
in time (the wrong number of fields, an unreadable time: ``unparseable``) or lies outside the
window (``outside_day_window``); a bad *cell* invalidates that signal only — it becomes NaN and is
counted by column as ``missing`` (an empty field) or ``unparseable`` (a number or mode label that
cannot be read).
"""

from __future__ import annotations

import codecs
import csv
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import charset_normalizer
import numpy as np
import pandas as pd

from trainclimate.data.formats import (
    CANONICAL,
    FORMATS,
    SOURCES,
    TEXT_COLUMNS,
    TIME_COLUMNS,
    ExportFormat,
    FormatError,
)

#: The field separators an export may use (a spreadsheet's CSV export follows its locale).
DELIMITERS = (";", ",", "\t")
#: What a file that is not UTF-8 is read as: the Windows and ISO code pages of Western Europe.
LEGACY_ENCODINGS = ("cp1252", "latin_1")
#: Bytes read at a time. [B]
BLOCK_BYTES = 1 << 20
#: Bytes from where a file stops being UTF-8 that its encoding is detected on. [B]
SAMPLE_BYTES = 1 << 20


class TimezoneError(FormatError):
    """Times without a zone in a format whose times carry one, and no zone given."""


@dataclass
class SourceTable:
    """A raw file read into its canonical table, with what reading had to drop (``dropped``:
    reason → rows) and invalidate (``cells``: (column, reason) → cells), and how the file was
    written: ``encoding``, ``delimiter``, the ``extra_columns`` it has besides the source's
    (ignored) and ``rows_read`` (its non-blank lines after the header)."""

    source: str
    campaign: str
    frame: pd.DataFrame
    dropped: Counter = field(default_factory=Counter)
    cells: Counter = field(default_factory=Counter)
    encoding: str = "utf-8"
    delimiter: str = ","
    extra_columns: tuple[str, ...] = ()
    rows_read: int = 0


def legacy_encoding(sample: bytes) -> str:
    """The encoding of bytes that are not UTF-8: what charset-normalizer finds among
    :data:`LEGACY_ENCODINGS` (Excel on a Swiss or German Windows writes Windows-1252). Raises
    :class:`FormatError` for bytes that are none of them."""
    best = charset_normalizer.from_bytes(sample, cp_isolation=list(LEGACY_ENCODINGS)).best()
    if best is None:
        raise FormatError("not text: neither UTF-8 nor Windows-1252")
    return best.encoding


def _fields(line: str, delimiter: str) -> list[str]:
    """One line's fields, quotes honoured within the line (a stray quote cannot swallow the
    lines after it)."""
    if '"' not in line:
        return line.split(delimiter)
    return next(csv.reader([line], delimiter=delimiter))


@dataclass(frozen=True)
class _Layout:
    fmt: ExportFormat
    source: str
    delimiter: str
    names: tuple[str, ...]  # the header's column names, a trailing empty one dropped

    def position(self, col: str) -> int | None:
        """Where canonical column ``col`` is in the file (None: an optional one it lacks)."""
        name = self.fmt.columns[self.source][col]
        return self.names.index(name) if name in self.names else None

    @property
    def extra(self) -> tuple[str, ...]:
        known = set(self.fmt.columns[self.source].values())
        return tuple(n for n in self.names if n not in known)


def _detect(header_line: str) -> _Layout:
    """The format, source and delimiter whose column names the header holds, in any order, with
    any other columns besides (a trailing separator's empty name dropped)."""
    for delimiter in DELIMITERS:
        names = [f.strip() for f in _fields(header_line, delimiter)]
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


def _localize(naive: pd.DatetimeIndex, zone: str, seen: set) -> pd.DatetimeIndex:
    """Wall times in ``zone`` → UTC. A wall time the autumn change repeats is resolved by order:
    its first occurrence in the file is summer time, a later one winter time (``seen`` holds the
    wall times read so far in the file); one the spring change skips → NaT."""
    try:
        return naive.tz_localize(zone, nonexistent="NaT", ambiguous="raise").tz_convert("UTC")
    except ValueError:  # a wall time the autumn change repeats
        pass
    ambiguous = np.zeros(len(naive), dtype=bool)
    for i, t in enumerate(naive):
        if t is pd.NaT:
            continue
        ambiguous[i] = t not in seen  # the first time this wall time is read: summer time
        seen.add(t)
    return naive.tz_localize(zone, nonexistent="NaT", ambiguous=ambiguous).tz_convert("UTC")


def _parse_times(
    text: pd.Series, fmt: ExportFormat, timezone: str | None, seen: set
) -> pd.DatetimeIndex:
    """Export times → UTC, with or without seconds; unparseable times or ones the spring change
    skips → NaT. Times without a zone are read in ``timezone``, else in the campaign's
    documented zone when its export writes local times (winter-spring: Europe/Zurich), else
    :class:`TimezoneError`."""
    if fmt.time_format.startswith("%Y-%m-%dT"):
        # ISO 8601: pandas' ISO parser is an order of magnitude faster than strptime
        times = pd.to_datetime(text, format="ISO8601", errors="coerce", utc=True)
        unzoned = pd.Series(False, index=text.index)
        maybe = ~text.str.endswith("Z").to_numpy(dtype=bool)
        if maybe.any():
            some = text[maybe]
            unzoned[maybe] = some.str.match(_ISO_TIME) & ~some.str.contains(_ZONED)
        if not unzoned.any():
            return pd.DatetimeIndex(times)  # (text that is no time at all: NaT, unparseable)
        if timezone is None:
            example = text[unzoned].iloc[0]
            raise TimezoneError(
                f"times without a time zone (e.g. {example!r}) in the {fmt.name} export, whose "
                "times are UTC with a Z: give their zone (--timezone, e.g. Europe/Zurich or UTC)"
            )
        naive = pd.to_datetime(text[unzoned], format="ISO8601", errors="coerce")
        times[unzoned] = _localize(pd.DatetimeIndex(naive), timezone, seen).as_unit(times.dt.unit)
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
    return index.tz_localize("UTC") if zone == "UTC" else _localize(index, zone, seen)


class _EncodingError(ValueError):
    """A file's bytes are not in the encoding tried, from about byte ``offset``."""

    def __init__(self, offset: int) -> None:
        super().__init__(f"not decodable from byte {offset}")
        self.offset = offset


def _lines(path: Path, encoding: str) -> Iterator[list[str]]:
    """The file's non-blank lines, decoded, in lists of about :data:`BLOCK_BYTES` (line ends
    ``\\n``, ``\\r\\n`` or ``\\r``). :class:`_EncodingError` if it is not in ``encoding``."""
    decoder = codecs.getincrementaldecoder(encoding)()
    carry = ""
    with path.open("rb") as f:
        while block := f.read(BLOCK_BYTES):
            try:
                decoded = decoder.decode(block)
            except UnicodeDecodeError as exc:
                raise _EncodingError(max(0, f.tell() - len(block) + exc.start - 4)) from None
            lines = re.split(r"\r\n?|\n", carry + decoded)
            carry = lines.pop()
            yield [line for line in lines if line.strip()]
        rest = carry + decoder.decode(b"", final=True)
        yield [line for line in re.split(r"\r\n?|\n", rest) if line.strip()]


class _Reading:
    """The state of one file being read: its layout, the rows kept so far and the counts."""

    def __init__(self, layout: _Layout, timezone: str | None, windows: dict | None) -> None:
        self.layout, self.timezone = layout, timezone
        self.window = (windows or {}).get(layout.source)
        self.frames: list[pd.DataFrame] = []
        self.dropped: Counter = Counter()
        self.cells: Counter = Counter()
        self.rows_read = 0
        self.seen: set = set()  # wall times read, for the autumn change's repeated hour

    def add(self, lines: list[str]) -> None:
        """Parse ``lines`` (data lines) and keep their canonical columns inside the window."""
        layout = self.layout
        width = len(layout.names)
        rows = []
        for line in lines:
            fields = _fields(line, layout.delimiter)
            while len(fields) > width and fields[-1].strip() == "":  # a trailing separator
                fields.pop()
            if len(fields) == width:
                rows.append(fields)
        self.rows_read += len(lines)
        self.dropped["unparseable"] += len(lines) - len(rows)
        if not rows:
            return
        fmt, source = layout.fmt, layout.source

        def column(col: str, keep=None) -> pd.Series:
            i = layout.position(col)
            picked = rows if keep is None else [r for r, k in zip(rows, keep, strict=True) if k]
            return pd.Series([r[i] for r in picked], dtype=object)

        out: dict[str, object] = {}
        placed = np.ones(len(rows), dtype=bool)
        for col in TIME_COLUMNS[source]:
            text = column(col)
            times = self._times(text)
            retry = np.flatnonzero(times.isna())
            if len(retry):  # blanks around a time (rare: only then stripped)
                stripped = self._times(text.iloc[retry].str.strip())
                times = pd.Series(times)
                times.iloc[retry] = stripped
                times = pd.DatetimeIndex(times)
            out[col] = times
            placed &= ~times.isna()
        self.dropped["unparseable"] += int((~placed).sum())
        inside = placed & self._inside(out)
        self.dropped["outside_day_window"] += int((placed & ~inside).sum())
        if not inside.any():
            return
        # only the rows kept are read further
        out = {col: times[inside] for col, times in out.items()}
        kept = int(inside.sum())
        for col in CANONICAL[source]:
            if col in TIME_COLUMNS[source]:
                continue
            if layout.position(col) is None:  # an optional column the file does not have
                out[col] = np.full(kept, np.nan)
                continue
            values = column(col, inside)
            if col in TEXT_COLUMNS[source] and col != "mode":
                out[col] = values.str.strip().to_numpy(dtype=object)
                continue
            empty = (values == "").to_numpy()
            if col == "mode":
                labels = {v: k for k, v in fmt.modes.items()}
                stripped = values.str.strip()
                parsed = stripped.map(labels).to_numpy(dtype=object)
                empty = (stripped == "").to_numpy()
                bad = pd.isna(parsed) & ~empty
            else:
                parsed = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float, copy=True)
                unread = np.isnan(parsed) & ~empty
                if unread.any():
                    # a comma in a number field is a decimal comma, whatever the campaign
                    comma = values[unread].str.replace(",", ".", regex=False)
                    parsed[unread] = pd.to_numeric(comma, errors="coerce")
                    empty = empty | (values.str.strip() == "").to_numpy()
                bad = np.isnan(parsed) & ~empty
                if col == "speed_kmh":
                    parsed = parsed / fmt.speed_factor
            self.cells[(col, "missing")] += int(empty.sum())
            self.cells[(col, "unparseable")] += int(bad.sum())
            out[col] = parsed
        self.frames.append(pd.DataFrame(out)[list(CANONICAL[source])])

    def _times(self, text: pd.Series) -> pd.DatetimeIndex:
        return _parse_times(text, self.layout.fmt, self.timezone, self.seen)

    def _inside(self, times: dict) -> np.ndarray:
        """Rows inside the window: a time in [start, end); a trip overlapping it."""
        if self.window is None:
            return np.ones(len(next(iter(times.values()))), dtype=bool)
        start, end = self.window
        if "departure" in times:
            return np.asarray((times["departure"] < end) & (times["arrival"] > start))
        return np.asarray((times["time"] >= start) & (times["time"] < end))

    def table(self, campaign: str, encoding: str) -> SourceTable:
        frame = pd.concat(self.frames, ignore_index=True) if self.frames else None
        if frame is None:
            frame = pd.DataFrame({c: [] for c in CANONICAL[self.layout.source]})
            for col in TIME_COLUMNS[self.layout.source]:
                frame[col] = pd.DatetimeIndex([], tz="UTC")
        return SourceTable(
            self.layout.source,
            campaign,
            frame,
            +self.dropped,
            +self.cells,
            encoding=encoding,
            delimiter=self.layout.delimiter,
            extra_columns=self.layout.extra,
            rows_read=self.rows_read,
        )


def read_source(
    path: str | Path,
    timezone: str | None = None,
    windows: dict[str, tuple[pd.Timestamp, pd.Timestamp]] | None = None,
) -> SourceTable:
    """Read one raw log file of either campaign into its canonical table (see the module).

    Times without a zone are read in ``timezone`` (an IANA name), by default in the campaign's
    (winter-spring: Europe/Zurich local time); a summer file whose times lack their ``Z`` needs
    ``timezone`` (:class:`TimezoneError` otherwise). The hour the autumn change repeats is
    resolved by order (first summer, then winter time). With ``windows`` (source → UTC start,
    end), only the rows of the file's source whose time is in [start, end) — trips that overlap
    it — are kept; the others are counted as ``outside_day_window``. Raises
    :class:`FormatError` (or OSError) for a file that is not a fleet log at all.
    """
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(len(codecs.BOM_UTF8))
    encoding = "utf-8-sig" if head == codecs.BOM_UTF8 else "utf-8"
    try:
        return _read(path, encoding, timezone, windows)
    except _EncodingError as exc:
        if encoding == "utf-8-sig":
            raise FormatError(
                "not text: a UTF-8 byte-order mark, then bytes that are not UTF-8"
            ) from None
        with path.open("rb") as f:  # a sample from where UTF-8 failed
            f.seek(max(0, exc.offset - SAMPLE_BYTES // 16))
            sample = f.read(SAMPLE_BYTES)
    try:
        return _read(path, legacy_encoding(sample), timezone, windows)
    except _EncodingError as exc:
        raise FormatError(f"not text: bytes from {exc.offset} are not Windows-1252") from None


def _read(path: Path, encoding: str, timezone: str | None, windows) -> SourceTable:
    reading = None
    for lines in _lines(path, encoding):
        if reading is None:
            if not lines:
                continue
            reading = _Reading(_detect(lines[0]), timezone, windows)
            lines = lines[1:]
        reading.add(lines)
    if reading is None:
        raise FormatError("empty file")
    return reading.table(reading.layout.fmt.name, encoding)
