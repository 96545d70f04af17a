"""The campaigns' export formats: times, units and decimals read back exactly; bad rows counted."""

import numpy as np
import pandas as pd
import pytest

from trainclimate.data.formats import (
    CANONICAL,
    SUMMER_FORMAT,
    WINTER_FORMAT,
    FormatError,
    log_path,
    parse_log_name,
    to_export,
    write_export,
)
from trainclimate.data.reader import read_source

WINTER_HVAC = "Zeit;Betriebsart;T_Soll;T_Raum_OG;T_Raum_MG;T_Raum_UG;Geschwindigkeit_kmh\n"
SUMMER_HVAC = "timestamp,hvac_mode,t_setpoint,t_room_upper,t_room_middle,t_room_lower,speed_mps\n"


def write(tmp_path, text, name="log.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def utc(*stamps):
    return pd.DatetimeIndex(pd.to_datetime(list(stamps), utc=True))


def assert_times_equal(actual, expected):
    assert pd.DatetimeIndex(actual).tz is not None
    np.testing.assert_array_equal(
        pd.DatetimeIndex(actual).as_unit("s").asi8, pd.DatetimeIndex(expected).as_unit("s").asi8
    )


def test_winter_decimal_commas_and_local_time_across_the_dst_change_read_as_utc(tmp_path):
    path = write(
        tmp_path,
        WINTER_HVAC
        + "22.02.2022 05:13:00;Normal;22,00;21,40;21,50;21,60;0,00\n"
        + "27.03.2022 01:59:00;Schlummer;22,50;20,10;20,20;20,30;12,50\n"
        # clocks go from 02:00 CET to 03:00 CEST: the next sample is one minute later
        + "27.03.2022 03:00:00;Aus;22,50;-1,25;0,00;19,90;0,00\n"
        + "28.03.2022 05:13:00;Normal;23,00;21,00;21,00;21,00;80,25\n",
    )
    table = read_source(path)
    assert (table.source, table.campaign) == ("hvac", "winter-spring")
    assert not table.dropped
    frame = table.frame
    assert list(frame.columns) == list(CANONICAL["hvac"])
    assert_times_equal(
        frame["time"],
        utc("2022-02-22 04:13", "2022-03-27 00:59", "2022-03-27 01:00", "2022-03-28 03:13"),
    )
    assert list(frame["mode"]) == ["regular", "slumber", "off", "regular"]
    np.testing.assert_array_equal(frame["t_ref_c"], [22.0, 22.5, 22.5, 23.0])
    np.testing.assert_array_equal(frame["t_room_up_c"], [21.4, 20.1, -1.25, 21.0])
    np.testing.assert_array_equal(frame["speed_kmh"], [0.0, 12.5, 0.0, 80.25])
    # a coach that does not meter its HVAC power: the optional column is NaN, not an error
    assert frame["p_hvac_kw"].isna().all() and table.extra_columns == ()


def test_a_local_time_that_does_not_exist_is_unparseable(tmp_path):
    path = write(
        tmp_path,
        WINTER_HVAC
        + "27.03.2022 01:59:00;Normal;22,00;21,40;21,50;21,60;0,00\n"
        + "27.03.2022 02:30:00;Normal;22,00;21,40;21,50;21,60;0,00\n"  # skipped by the DST change
        + "27.03.2022 03:00:00;Normal;22,00;21,40;21,50;21,60;0,00\n",
    )
    table = read_source(path)
    assert table.dropped == {"unparseable": 1}
    assert_times_equal(table.frame["time"], utc("2022-03-27 00:59", "2022-03-27 01:00"))


def test_summer_speed_in_metres_per_second_comes_back_in_kmh(tmp_path):
    path = write(
        tmp_path,
        SUMMER_HVAC
        + "2023-07-04T05:13:02Z,REGULAR,24.00,24.10,24.20,24.30,10.00\n"
        + "2023-07-04T05:13:04Z,SLUMBER,24.00,24.10,24.20,24.30,0.50\n"
        + "2023-07-04T05:13:06Z,OFF,24.00,24.10,24.20,24.30,0.00\n",
    )
    table = read_source(path)
    assert (table.source, table.campaign) == ("hvac", "summer")
    assert not table.dropped
    assert_times_equal(
        table.frame["time"],
        utc("2023-07-04 05:13:02", "2023-07-04 05:13:04", "2023-07-04 05:13:06"),
    )
    assert list(table.frame["mode"]) == ["regular", "slumber", "off"]
    np.testing.assert_allclose(table.frame["speed_kmh"], [36.0, 1.8, 0.0], rtol=1e-12)


def canonical(source):
    """A small canonical table of ``source`` whose values survive the exports' rounding."""
    times = pd.date_range("2022-03-26 23:58", periods=5, freq="1min", tz="UTC")
    if source == "hvac":
        return pd.DataFrame(
            {
                "time": times,
                "mode": ["regular", "regular", "slumber", "off", "regular"],
                "t_ref_c": [22.0, 22.5, 22.5, 21.0, 24.25],
                "t_room_up_c": [21.4, -3.1, 0.0, 35.75, 22.0],
                "t_room_mid_c": [21.5, 21.6, 21.7, 21.8, 21.9],
                "t_room_low_c": [20.1, 20.2, 20.3, 20.4, 20.5],
                "speed_kmh": [0.0, 36.0, 72.0, 126.0, 3.6],  # whole m/s, exact in summer
                "p_hvac_kw": [3.25, 14.8, 1.1, 0.0, 22.05],
            }
        )
    if source == "weather":
        return pd.DataFrame(
            {
                "time": times,
                "latitude_deg": [47.377900, 47.380123, 47.381234, 47.391400, 47.499900],
                "longitude_deg": [8.540300, 8.530001, 8.520002, 8.488900, 8.723600],
                "t_amb_c": [-4.25, -4.2, 0.0, 1.1, 12.5],
                "ghi_w_m2": [0.0, 12.5, 340.0, 812.75, 0.0],
                "solar_elevation_deg": [-42.53, -10.0, 5.5, 30.0, 61.2],
                "solar_azimuth_deg": [50.13, 90.0, 180.0, 270.5, 359.99],
            }
        )
    return pd.DataFrame(
        {
            "train": ["124", "124"],
            "departure": times[[0, 2]],
            "arrival": times[[1, 4]],
            "origin": ["Zürich HB", "Wädenswil"],
            "destination": ["Pfäffikon SZ", "Zürich Hardbrücke"],
            "occupancy_pct": [13.72, 0.5],
        }
    )


@pytest.mark.parametrize("fmt", [WINTER_FORMAT, SUMMER_FORMAT], ids=lambda f: f.name)
@pytest.mark.parametrize("source", ["hvac", "weather", "trips"])
def test_export_write_read_round_trips_the_canonical_table(tmp_path, fmt, source):
    frame = canonical(source)
    path = tmp_path / "log.csv"
    write_export(to_export(frame, source, fmt), path, fmt)
    first_line = path.read_text(encoding="utf-8").splitlines()[0]
    assert first_line == fmt.sep.join(fmt.columns[source][c] for c in CANONICAL[source])
    table = read_source(path)
    assert (table.source, table.campaign) == (source, fmt.name)
    assert not table.dropped
    back = table.frame
    assert list(back.columns) == list(frame.columns)
    for col in CANONICAL[source]:
        if col in ("time", "departure", "arrival"):
            assert_times_equal(back[col], frame[col])
        elif col in ("mode", "train", "origin", "destination"):
            assert list(back[col]) == list(frame[col])
        else:
            np.testing.assert_allclose(back[col], frame[col], rtol=0, atol=1e-9, err_msg=col)


def test_winter_export_of_the_short_dst_day_reads_back_minute_by_minute(tmp_path):
    # the coach-day of 2022-03-26 runs 03:00 CET to 03:00 CEST: 23 h, no local time twice or never
    times = pd.date_range("2022-03-26 02:00", "2022-03-27 01:00", freq="1min", tz="UTC",
                          inclusive="left")  # fmt: skip
    frame = pd.DataFrame(
        {
            "time": times,
            "mode": "regular",
            "t_ref_c": 22.0,
            "t_room_up_c": 21.0,
            "t_room_mid_c": 21.0,
            "t_room_low_c": 21.0,
            "speed_kmh": 0.0,
        }
    )
    path = tmp_path / "log.csv"
    write_export(to_export(frame, "hvac", WINTER_FORMAT), path, WINTER_FORMAT)
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[1].startswith("26.03.2022 03:00:00;")
    assert lines[-1].startswith("27.03.2022 01:59:00;")  # CET; the next minute is 03:00 CEST
    table = read_source(path)
    assert len(times) == 23 * 60 and not table.dropped
    assert_times_equal(table.frame["time"], times)


def test_garbage_lines_and_wrong_field_counts_are_unparseable(tmp_path):
    good = "22.02.2022 05:{:02d}:00;Normal;22,00;21,40;21,50;21,60;0,00\n"
    path = write(
        tmp_path,
        WINTER_HVAC
        + good.format(0)
        + "### logger restart ###;;;;;;\n"  # the generator's garbage line
        + good.format(1)
        + "22.02.2022 05:02:00;Normal;22,00\n"  # too few fields
        + "22.02.2022 05:03:00;Normal;22,00;21,40;21,50;21,60;0,00;7\n"  # too many
        + "22.02.2022 05:04:00;Normal;22,00;21,4x;21,50;21,60;0,00\n"  # not a number: a cell
        + "22.02.2022 05:05:00;Turbo;22,00;21,40;21,50;21,60;0,00\n"  # unknown mode: a cell
        + '"logger dump\n'  # a stray quote must not swallow the lines after it
        + '22.02.2022 05:06:00;Normal;"22,00;21,40;21,50;21,60;0,00\n'  # nor inside a row
        + good.format(6)
        + "\n"  # blank lines are not rows
        + "2022-02-22T05:07:00Z;Normal;22,00;21,40;21,50;21,60;0,00\n"  # the other time format
        + good.format(8),
    )
    table = read_source(path)
    assert table.dropped == {"unparseable": 6}
    assert table.cells == {("t_room_up_c", "unparseable"): 1, ("mode", "unparseable"): 1}
    assert_times_equal(
        table.frame["time"],
        utc(*(f"2022-02-22 04:0{m}" for m in (0, 1, 4, 5, 6, 8))),
    )
    # the bad cell invalidates its signal only; the row's other readings stay
    row = table.frame.set_index("time").loc[utc("2022-02-22 04:04")[0]]
    assert np.isnan(row["t_room_up_c"]) and (row["t_room_mid_c"], row["mode"]) == (21.5, "regular")
    assert pd.isna(table.frame["mode"].iloc[3]) and table.frame["t_ref_c"].iloc[3] == 22.0


def test_an_empty_field_is_read_as_missing_not_dropped(tmp_path):
    path = write(
        tmp_path,
        SUMMER_HVAC
        + "2023-07-04T05:13:02Z,REGULAR,24.00,,24.20,24.30,10.00\n"
        + "2023-07-04T05:13:04Z,,24.00,24.10,24.20,24.30,\n",
    )
    table = read_source(path)
    assert not table.dropped
    frame = table.frame
    assert np.isnan(frame.loc[0, "t_room_up_c"]) and frame.loc[0, "t_room_mid_c"] == 24.2
    assert pd.isna(frame.loc[1, "mode"]) and np.isnan(frame.loc[1, "speed_kmh"])


@pytest.mark.parametrize(
    ("content", "error"),
    [
        (b"", FormatError),
        (b"\n\n", FormatError),
        (b"time,t_amb_c,ghi_w_m2\n2023-07-04T05:00:00Z,20.0,100.0\n", FormatError),
        (bytes(range(128, 256)) * 4, FormatError),  # neither UTF-8 nor Windows-1252
    ],
    ids=["empty", "blank", "foreign-header", "binary"],
)
def test_a_file_that_is_no_fleet_log_raises(tmp_path, content, error):
    path = tmp_path / "log.csv"
    path.write_bytes(content)
    with pytest.raises(error):
        read_source(path)


def test_log_file_names_follow_the_layout(tmp_path):
    path = log_path(tmp_path, "summer", "weather", "124", "124B", "2023-07-04")
    assert path == tmp_path / "summer" / "weather" / "124_124B_2023-07-04.csv"
    assert parse_log_name(path) == ("124", "124B", "2023-07-04")
    assert parse_log_name(tmp_path / "notes.csv") is None
    assert parse_log_name(tmp_path / "124_124B_2023-07-04.txt") is None
