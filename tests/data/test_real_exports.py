"""Real exports of the same logs: each way a spreadsheet or a logger's export tool writes a file
reads back to exactly the table of the plain export, and the file's report says how it was
written."""

import numpy as np
import pandas as pd
import pytest

from trainclimate.data.dataset import discover
from trainclimate.data.reader import TimezoneError, read_source

WINTER_HVAC = [
    ["Zeit", "Betriebsart", "T_Soll", "T_Raum_OG", "T_Raum_MG", "T_Raum_UG", "Geschwindigkeit_kmh"],
    ["22.02.2022 05:13:00", "Normal", "22,00", "21,40", "21,50", "21,60", "0,00"],
    ["22.02.2022 05:14:00", "Schlummer", "22,50", "20,10", "20,20", "20,30", "12,50"],
    ["22.02.2022 05:15:00", "Normal", "23,00", "21,00", "21,00", "21,00", "80,25"],
]
WINTER_TRIPS = [
    ["Zug", "Abfahrt", "Ankunft", "Von", "Nach", "Belegung_Prozent"],
    ["124", "22.02.2022 06:01:00", "22.02.2022 06:40:00", "Zürich HB", "Pfäffikon SZ", "35,50"],
    ["124", "22.02.2022 07:02:00", "22.02.2022 07:41:00", "Pfäffikon SZ", "Zürich HB", "61,00"],
]
SUMMER_HVAC = [
    ["timestamp", "hvac_mode", "t_setpoint", "t_room_upper", "t_room_middle", "t_room_lower",
     "speed_mps"],
    ["2023-07-04T05:13:00Z", "REGULAR", "24.00", "24.10", "24.20", "24.30", "10.00"],
    ["2023-07-04T05:14:00Z", "SLUMBER", "24.50", "24.60", "24.70", "24.80", "0.00"],
]  # fmt: skip


def text(rows: list[list[str]], sep: str = ";", line: str = "\n") -> str:
    return "".join(sep.join(r) + line for r in rows)


def plain(tmp_path, rows, sep=";") -> pd.DataFrame:
    path = tmp_path / "plain.csv"
    path.write_text(text(rows, sep), encoding="utf-8")
    table = read_source(path)
    assert not table.dropped and len(table.frame) == len(rows) - 1
    return table.frame


def read(tmp_path, data: bytes):
    path = tmp_path / "variant.csv"
    path.write_bytes(data)
    return read_source(path)


def same(table, expected: pd.DataFrame) -> None:
    assert not table.dropped
    pd.testing.assert_frame_equal(table.frame, expected)


def test_a_utf8_byte_order_mark_and_windows_line_ends(tmp_path):
    table = read(tmp_path, b"\xef\xbb\xbf" + text(WINTER_HVAC, line="\r\n").encode("utf-8"))
    same(table, plain(tmp_path, WINTER_HVAC))
    assert (table.encoding, table.delimiter, table.rows_read) == ("utf-8-sig", ";", 3)


def test_windows_1252_station_names(tmp_path):
    table = read(tmp_path, text(WINTER_TRIPS).encode("cp1252"))
    same(table, plain(tmp_path, WINTER_TRIPS))
    assert table.encoding in ("cp1252", "latin_1")
    assert list(table.frame["origin"]) == ["Zürich HB", "Pfäffikon SZ"]


def test_quoted_fields_and_a_trailing_separator(tmp_path):
    quoted = "".join(";".join(f'"{v}"' for v in r) + ";\n" for r in WINTER_HVAC)
    same(read(tmp_path, quoted.encode()), plain(tmp_path, WINTER_HVAC))


def test_times_without_seconds(tmp_path):
    rows = [WINTER_HVAC[0]] + [[r[0][:-3], *r[1:]] for r in WINTER_HVAC[1:]]
    same(read(tmp_path, text(rows).encode()), plain(tmp_path, WINTER_HVAC))


def test_columns_in_another_order_with_others_besides(tmp_path):
    order = [6, 0, 3, 1, 5, 2, 4]
    rows = [
        [r[i] for i in order] + [extra]
        for r, extra in zip(WINTER_HVAC, ["Fahrer", "A", "B", "C"], strict=True)
    ]
    table = read(tmp_path, text(rows).encode())
    same(table, plain(tmp_path, WINTER_HVAC))
    assert table.extra_columns == ("Fahrer",)


@pytest.mark.parametrize(
    ("sep", "decimal"),
    [(";", ","), ("\t", "."), ("\t", ",")],
    ids=["semicolon", "tab", "tab-comma"],
)
def test_the_summer_export_resaved_with_another_separator_or_decimal_comma(tmp_path, sep, decimal):
    rows = [SUMMER_HVAC[0]] + [[c.replace(".", decimal) for c in r] for r in SUMMER_HVAC[1:]]
    table = read(tmp_path, text(rows, sep).encode())
    same(table, plain(tmp_path, SUMMER_HVAC, sep=","))
    assert table.delimiter == sep


def test_file_extensions_in_any_case_are_found(tmp_path):
    for name in ("124_124A_2022-02-22.CSV", "124_124B_2022-02-22.Csv", "124_124C_2022-02-22.txt"):
        path = tmp_path / "winter-spring" / "hvac" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text(WINTER_HVAC), encoding="utf-8")
    groups, skipped = discover(tmp_path)
    assert sorted(k[2] for k in groups) == ["124A", "124B"] and skipped == []


def test_small_sensor_offsets_are_read_as_zero_and_counted():
    from trainclimate.data.pipeline import Counts, PipelineSettings, clean

    times = pd.date_range("2022-02-22 04:00", periods=5, freq="1min", tz="UTC")
    hvac = pd.DataFrame(
        {
            "time": times,
            "mode": ["regular"] * 5,
            "t_ref_c": 22.0,
            "t_room_up_c": 21.0,
            "t_room_mid_c": 21.0,
            "t_room_low_c": 21.0,
            # standing still: −0.1 and −0.5 km/h are offsets, −0.6 is out of range
            "speed_kmh": [0.0, -0.1, -0.5, -0.6, 12.0],
        }
    )
    counts = Counts()
    out = clean(hvac, "hvac", counts, PipelineSettings())
    np.testing.assert_array_equal(out["speed_kmh"], [0.0, 0.0, 0.0, np.nan, 12.0])
    assert counts.repaired["clipped_offset"] == 2
    assert counts.cells["hvac"] == {("speed_kmh", "out_of_range"): 1}
    weather = pd.DataFrame(
        {
            "time": times,
            "latitude_deg": 47.4,
            "longitude_deg": 8.5,
            "t_amb_c": 1.0,
            "ghi_w_m2": [-1.5, -5.0, -5.1, 0.0, 3.0],  # a pyranometer's night offset
            "solar_elevation_deg": -20.0,
            "solar_azimuth_deg": 10.0,
        }
    )
    counts = Counts()
    out = clean(weather, "weather", counts, PipelineSettings())
    np.testing.assert_array_equal(out["ghi_w_m2"], [0.0, 0.0, np.nan, 0.0, 3.0])
    assert counts.repaired["clipped_offset"] == 2
    assert counts.cells["weather"] == {("ghi_w_m2", "out_of_range"): 1}
    assert list(out["t_amb_c"]) == [1.0] * 5  # the row's other readings stay


def test_the_hour_the_autumn_change_repeats_is_resolved_by_order(tmp_path):
    rows = [WINTER_HVAC[0]] + [
        [f"30.10.2022 {hm}:00", "Normal", "22,00", "21,40", "21,50", "21,60", "0,00"]
        for hm in ("01:59", "02:00", "02:30", "02:59", "02:00", "02:30", "03:00")
    ]
    table = read(tmp_path, text(rows).encode())
    assert not table.dropped
    utc = pd.DatetimeIndex(table.frame["time"]).strftime("%H:%M").tolist()
    # 02:00–02:59 CEST (00:00 UTC …), then 02:00–02:59 CET (01:00 UTC …), then 03:00 CET
    assert utc == ["23:59", "00:00", "00:30", "00:59", "01:00", "01:30", "02:00"]


def test_summer_times_without_their_zone_need_one(tmp_path):
    rows = [SUMMER_HVAC[0]] + [[r[0].rstrip("Z"), *r[1:]] for r in SUMMER_HVAC[1:]]
    path = tmp_path / "variant.csv"
    path.write_text(text(rows, ","), encoding="utf-8")
    with pytest.raises(TimezoneError, match=r"without a time zone .*--timezone"):
        read_source(path)
    expected = plain(tmp_path, SUMMER_HVAC, sep=",")
    pd.testing.assert_frame_equal(read_source(path, timezone="UTC").frame, expected)
    local = read_source(path, timezone="Europe/Zurich").frame
    # written in Zurich summer time: two hours earlier in UTC
    assert (expected["time"] - local["time"] == pd.Timedelta(hours=2)).all()


def test_a_repeated_time_with_other_values_is_reported_and_the_first_kept(caplog):
    import logging

    from trainclimate.data.pipeline import Counts, PipelineSettings, clean

    times = pd.to_datetime(
        ["2022-02-22 04:00", "2022-02-22 04:01", "2022-02-22 04:01", "2022-02-22 04:01"], utc=True
    )
    hvac = pd.DataFrame(
        {
            "time": times,
            "mode": "regular",
            "t_ref_c": 22.0,
            "t_room_up_c": [21.0, 21.5, 21.5, 25.0],  # an exact copy, then a conflicting one
            "t_room_mid_c": 21.0,
            "t_room_low_c": 21.0,
            "speed_kmh": 0.0,
        }
    )
    counts = Counts()
    with caplog.at_level(logging.WARNING, logger="trainclimate.data.pipeline"):
        out = clean(hvac, "hvac", counts, PipelineSettings())
    assert list(out["t_room_up_c"]) == [21.0, 21.5]
    assert counts.dropped["duplicate"] == 1 and counts.dropped["conflicting_duplicate"] == 1
    [message] = [r.getMessage() for r in caplog.records]
    assert "first in the file is kept" in message and "25.0" in message


def test_a_line_that_is_no_time_at_all_is_unparseable_not_a_missing_zone(tmp_path):
    rows = [*SUMMER_HVAC, ["### logger restart ###", "", "", "", "", "", ""]]
    path = tmp_path / "variant.csv"
    path.write_text(text(rows, ","), encoding="utf-8")
    table = read_source(path)
    assert table.dropped == {"unparseable": 1} and len(table.frame) == 2
    # with and without zones mixed, --timezone reads the ones without
    rows = [SUMMER_HVAC[0], SUMMER_HVAC[1], [SUMMER_HVAC[2][0].rstrip("Z"), *SUMMER_HVAC[2][1:]]]
    path.write_text(text(rows, ","), encoding="utf-8")
    with pytest.raises(TimezoneError):
        read_source(path)
    expected = plain(tmp_path, SUMMER_HVAC, sep=",")
    pd.testing.assert_frame_equal(read_source(path, timezone="UTC").frame, expected)


def test_a_file_read_in_small_blocks_gives_the_same_table(tmp_path, monkeypatch):
    """Blocks split lines, a CRLF pair, a Windows-1252 character and the repeated autumn hour
    anywhere: the table is the one read in one piece."""
    from trainclimate.data import reader

    rows = [WINTER_HVAC[0]] + [
        [f"30.10.2022 {hm}", "Normal", "22,00", f"21,{i:02d}", "21,50", "21,60", "0,00", note]
        for i, (hm, note) in enumerate(
            [(f"{h:02d}:{m:02d}", "") for h in (1, 2) for m in range(0, 60, 5)]
            + [(f"02:{m:02d}", "Türe offen" if m == 30 else "") for m in range(0, 60, 5)]
            + [(f"03:{m:02d}", "") for m in range(0, 60, 5)]
        )
    ]
    rows[0] = [*rows[0], "Bemerkung"]
    data = b"\r\n".join(";".join(r).encode("cp1252") for r in rows) + b"\r\n"
    path = tmp_path / "variant.csv"
    path.write_bytes(data)
    whole = read_source(path)
    assert whole.encoding == "cp1252" and whole.rows_read == 48 and not whole.dropped
    for block in (1, 7, 64, 333):
        monkeypatch.setattr(reader, "BLOCK_BYTES", block)
        table = read_source(path)
        pd.testing.assert_frame_equal(table.frame, whole.frame)
        assert (table.rows_read, table.encoding, table.dropped) == (48, "cp1252", {})
    utc = pd.DatetimeIndex(whole.frame["time"])
    assert utc.is_monotonic_increasing and utc.is_unique  # the repeated hour by order


def test_rows_outside_the_window_are_counted_not_kept(tmp_path):
    path = tmp_path / "variant.csv"
    path.write_text(text(WINTER_HVAC), encoding="utf-8")
    window = (pd.Timestamp("2022-02-22 04:15", tz="UTC"), pd.Timestamp("2022-02-22 05", tz="UTC"))
    table = read_source(path, windows={"hvac": window, "trips": (window[0], window[0])})
    assert table.dropped == {"outside_day_window": 2} and len(table.frame) == 1
    assert table.frame["time"].iloc[0] == window[0]
