"""The seeded raw-log generator and the dataset built from it: layout, accounting, determinism."""

import dataclasses
import re

import numpy as np
import pandas as pd
import pytest

from trainclimate.data import fleetlogs
from trainclimate.data.dataset import build_dataset
from trainclimate.data.formats import CANONICAL, WINTER_FORMAT
from trainclimate.data.reader import read_source
from trainclimate.data.trajectory import read_trajectories

CAMPAIGN = fleetlogs.WINTER_SPRING
#: On 2022-02-22 coach 124A stands in the depot all day and 44A is in service.
SMALL = dict(campaigns=(CAMPAIGN,), max_days=1, max_coaches=2)


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    summary = fleetlogs.generate(root / "raw", **SMALL)
    return root, summary


@pytest.fixture(scope="module")
def built(raw):
    root, _ = raw
    return build_dataset(root / "raw", root / "out")


def csv_files(root):
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*.csv"))


def data_lines(path):
    return [line for line in path.read_text(encoding="utf-8").splitlines()[1:] if line.strip()]


def test_defects_none_sets_every_rate_to_zero():
    clean = fleetlogs.Defects.none()
    assert all(getattr(clean, f.name) == 0.0 for f in dataclasses.fields(clean))
    assert fleetlogs.Defects().duplicate_row == 0.002


def test_a_plan_is_drawn_from_its_coach_days_seed():
    rates = fleetlogs.Defects()
    plan = fleetlogs.plan_day(CAMPAIGN, 1, 0, rates)
    assert plan == fleetlogs.plan_day(CAMPAIGN, 1, 0, rates)
    assert plan.seed != fleetlogs.plan_day(CAMPAIGN, 1, 1, rates).seed
    assert (plan.coach, plan.train, plan.day) == ("44A", "44", "2022-02-22")
    assert plan.in_service and not fleetlogs.plan_day(CAMPAIGN, 0, 0, rates).in_service
    assert plan.start < plan.first_departure < plan.last_arrival < plan.end
    # a coach-day runs 03:00 to 03:00 local time: 23 h over the spring DST change
    dst = CAMPAIGN.days.index("2022-03-26")
    short = fleetlogs.plan_day(CAMPAIGN, 0, dst, rates)
    assert short.start == pd.Timestamp("2022-03-26 02:00", tz="UTC")
    assert short.end - short.start == pd.Timedelta(hours=23)
    normal = fleetlogs.plan_day(CAMPAIGN, 0, dst + 1, rates)
    assert normal.end - normal.start == pd.Timedelta(hours=24)


def test_generation_writes_one_file_per_source_coach_and_day(raw):
    root, summary = raw
    assert (summary.coach_days, summary.coach_days_logged, summary.files) == (2, 2, 6)
    assert csv_files(root / "raw") == [
        f"winter-spring/{source}/{name}_2022-02-22.csv"
        for source in ("hvac", "trips", "weather")
        for name in ("124_124A", "44_44A")
    ]
    for source in ("hvac", "trips", "weather"):
        path = root / "raw" / "winter-spring" / source / "44_44A_2022-02-22.csv"
        first = path.read_text(encoding="utf-8").splitlines()[0]
        assert first == ";".join(WINTER_FORMAT.columns[source][c] for c in CANONICAL[source])
    total = sum(len(data_lines(p)) for p in (root / "raw").rglob("*.csv"))
    assert summary.rows == total
    # the parked coach makes no trip; the HVAC logs a sample a minute, the weather every 10 min
    assert data_lines(root / "raw/winter-spring/trips/124_124A_2022-02-22.csv") == []
    hvac = read_source(root / "raw/winter-spring/hvac/124_124A_2022-02-22.csv").frame
    assert set(hvac["mode"]) == {"off"}
    times = pd.DatetimeIndex(hvac["time"])
    assert times.min() >= pd.Timestamp("2022-02-22 02:00", tz="UTC")
    assert times.max() <= pd.Timestamp("2022-02-23 01:59", tz="UTC")
    assert (times.second == 0).all()
    weather = read_source(root / "raw/winter-spring/weather/44_44A_2022-02-22.csv").frame
    assert (pd.DatetimeIndex(weather["time"]).minute % 10 == 0).all()


def test_the_build_accounts_for_every_raw_row_and_defect(raw, built):
    root, _ = raw
    files = sorted((root / "raw").rglob("*.csv"))
    assert built.unreadable_files == [] and built.coach_days == 2
    assert built.raw_rows == sum(len(data_lines(p)) for p in files)
    # independent counts: the generator's garbage lines are the only unparseable rows, and a
    # duplicate is a row repeating a time already logged
    garbage = sum(line.startswith("### logger restart") for p in files for line in data_lines(p))
    repeats = 0
    for p in files:
        frame = read_source(p).frame
        key = "departure" if "departure" in frame else "time"
        repeats += len(frame) - frame[key].nunique()
    assert built.dropped_rows.get("unparseable", 0) == garbage
    assert built.dropped_rows["duplicate"] == repeats > 0


def test_only_the_in_service_coach_gives_trajectories_all_in_regular_mode(raw, built):
    root, _ = raw
    assert [(r["campaign"], r["sampling_min"]) for r in built.table] == [
        ("winter-spring", 1),
        ("winter-spring", 5),
        ("winter-spring", 10),
    ]
    for row in built.table:
        found = read_trajectories(root / "out" / f"trajectories_{row['sampling_min']}min.parquet")
        assert row["trajectories"] == len(found) >= 1
        assert row["mean_points"] == round(sum(map(len, found)) / len(found), 1)
        assert {t.coach for t in found} == {"44A"}
    hvac = read_source(root / "raw/winter-spring/hvac/44_44A_2022-02-22.csv").frame
    mode = hvac.drop_duplicates("time").set_index("time")["mode"]
    minutes = pd.DatetimeIndex(
        [t for traj in read_trajectories(root / "out" / "trajectories_1min.parquet")
         for t in traj.time]
    )  # fmt: skip
    logged = minutes[minutes.isin(mode.index)]
    assert (mode[logged] == "regular").all()
    # the minutes without a logged row are the short gaps the pipeline filled
    assert len(minutes) - len(logged) <= built.repaired_rows.get("short_gap_minutes", 0)


def test_the_same_seed_writes_the_same_files_and_the_same_dataset(raw, built, tmp_path):
    root, summary = raw
    again = fleetlogs.generate(tmp_path / "raw", **SMALL)
    assert again == summary
    assert csv_files(tmp_path / "raw") == csv_files(root / "raw")
    for name in csv_files(root / "raw"):
        assert (tmp_path / "raw" / name).read_bytes() == (root / "raw" / name).read_bytes(), name
    rebuilt = build_dataset(tmp_path / "raw", tmp_path / "out")
    assert rebuilt.table == built.table and rebuilt.dropped_rows == built.dropped_rows
    for step in (1, 5, 10):
        name = f"trajectories_{step}min.parquet"
        assert (tmp_path / "out" / name).read_bytes() == (root / "out" / name).read_bytes()


def test_the_generator_names_the_files_it_corrupted(tmp_path):
    rates = dataclasses.replace(fleetlogs.Defects(), unreadable_file=0.5)
    summary = fleetlogs.generate(tmp_path / "raw", defects=rates, **SMALL)
    assert summary.corrupted, "with half the files corrupted, some are"
    unreadable = []
    for path in sorted((tmp_path / "raw").rglob("*.csv")):
        try:
            read_source(path)
        except (UnicodeDecodeError, ValueError):
            unreadable.append(str(path))
    assert sorted(summary.corrupted) == unreadable


def test_every_row_of_every_source_is_accounted_for_under_every_defect(tmp_path):
    """read == kept + sum(dropped) per source, with each of the generator's defects made
    frequent enough to occur in a small campaign, and files the pipeline cannot use besides."""
    rates = fleetlogs.Defects(
        duplicate_row=0.02,
        out_of_order_block=1.0,
        spike_value=0.005,
        empty_value=0.005,
        garbage_line=1.0,
        unreadable_file=0.2,
        missing_trip=0.2,
    )
    raw = tmp_path / "raw"
    generated = fleetlogs.generate(raw, **{**SMALL, "max_coaches": 3}, defects=rates)
    (raw / "winter-spring" / "hvac" / "notes.csv").write_text("a\nb\nc\n")  # not a log's name
    summary = build_dataset(raw, tmp_path / "out", expected_unreadable=generated.corrupted)
    assert summary.unreadable_files  # some files were made unreadable
    for source, rows in summary.rows.items():
        assert rows["read"] == rows["kept"] + sum(rows["dropped"].values()), (source, rows)
    assert set(summary.rows) == {"hvac", "weather", "trips"}
    reasons = {r for rows in summary.rows.values() for r in rows["dropped"]}
    assert {"duplicate", "unparseable", "unrecognised_file"} <= reasons
    # the file-level reasons are counted in rows, like those of single rows
    assert summary.rows["hvac"]["dropped"]["unrecognised_file"] == 2
    # bad cells are counted by column, their rows kept
    assert {"missing", "out_of_range", "spike"} <= set(summary.invalid_cells)
    assert {"missing", "spike"} <= set(summary.rows["hvac"]["invalid_cells"]["t_room_up_c"])


def _as_a_spreadsheet_saves_it(path, out):
    """The file re-saved as Excel on a Swiss Windows would: Windows-1252, CRLF, every field
    quoted with a trailing separator, times without seconds, the columns reversed and one
    added."""
    lines = path.read_text(encoding="utf-8").splitlines()
    rows = [line.split(";") for line in lines]
    rows = [[*reversed(r), "Bemerkung" if i == 0 else ""] for i, r in enumerate(rows)]
    rows = [[re.sub(r"^(\d\d\.\d\d\.\d{4} \d\d:\d\d):00$", r"\1", f) for f in r] for r in rows]
    text = "".join(";".join(f'"{f}"' for f in r) + ";\r\n" for r in rows)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(text.encode("cp1252"))


def test_a_campaign_re_saved_as_a_spreadsheet_gives_the_same_trajectories(raw, built, tmp_path):
    root, _ = raw
    copy = tmp_path / "raw"
    for path in (root / "raw").rglob("*.csv"):
        _as_a_spreadsheet_saves_it(path, copy / path.relative_to(root / "raw"))
    again = build_dataset(copy, tmp_path / "out")
    assert again.table == built.table and again.rows == built.rows
    assert {f["encoding"] for f in again.files} <= {"cp1252", "latin_1", "utf-8"}
    assert {tuple(f["extra_columns"]) for f in again.files} == {("Bemerkung",)}
    for step in (1, 5, 10):
        name = f"trajectories_{step}min.parquet"
        mine, theirs = (read_trajectories(d / name) for d in (tmp_path / "out", root / "out"))
        assert len(mine) == len(theirs) >= 1
        assert all(t.frame().equals(u.frame()) for t, u in zip(mine, theirs, strict=True))


def test_the_power_meter_reads_the_mean_over_each_interval():
    grid = np.arange(0.0, 60.0, 10.0)  # a power held over 10-s steps
    power_w = np.array([1000.0, 2000.0, 3000.0, 4000.0, 5000.0, 6000.0])
    # 1-min readings from 0 s, 2-s readings inside a step, a reading straddling two steps
    kw = fleetlogs._metered_kw(np.array([0.0, 12.0, 25.0]), grid, power_w, 60.0)
    np.testing.assert_allclose(kw[0], 3.5)
    kw = fleetlogs._metered_kw(np.array([12.0, 25.0, 28.0]), grid, power_w, 4.0)
    np.testing.assert_allclose(kw, [2.0, 3.0, 3.5])


def test_the_hvac_log_meters_power_and_the_trajectories_carry_it(raw, built):
    root, _ = raw
    for path in (root / "raw").rglob("hvac/*.csv"):
        if path.stat().st_size > 1000:  # (not a corrupted one)
            assert "P_Klima_kW" in path.read_text(encoding="utf-8").splitlines()[0]
    one = read_trajectories(root / "out" / "trajectories_1min.parquet")
    five = read_trajectories(root / "out" / "trajectories_5min.parquet")
    p = np.concatenate([t.p_kw for t in one])
    assert np.isfinite(p).mean() > 0.95 and np.nanmin(p) >= 0.0 and 1.0 < np.nanmean(p) < 30.0
    # 5-min power: the mean of its five minutes
    t1, t5 = one[0], next(t for t in five if t.time[0] >= one[0].time[0])
    i = t1.time.get_indexer(t5.time[:3])
    expected = [t1.p_kw[k : k + 5].mean() for k in i]
    np.testing.assert_allclose(t5.p_kw[:3], expected, rtol=1e-12)
    # the power is carried, not required: Table I is that of logs without a meter
    assert built.rows["hvac"]["invalid_cells"].get("p_hvac_kw", {}).get("missing", 0) >= 0


def test_given_coach_parameters_are_every_generated_coachs(tmp_path):
    """A fan drawing 1 kW more shows in the metered power whenever the unit runs."""
    from trainclimate.sim.params import CoachParams

    clean = fleetlogs.Defects.none()
    base, more = CoachParams(), CoachParams(fan_supply_w=CoachParams().fan_supply_w + 1000.0)
    days = dict(campaigns=(CAMPAIGN,), max_days=1, max_coaches=2, defects=clean)
    fleetlogs.generate(tmp_path / "a", coach_params=base, **days)
    fleetlogs.generate(tmp_path / "b", coach_params=more, **days)
    diffs = []
    for a in sorted((tmp_path / "a").rglob("hvac/*.csv")):  # (one coach in the depot, HVAC off)
        b = tmp_path / "b" / a.relative_to(tmp_path / "a")
        pa_, pb = (read_source(p).frame for p in (a, b))
        running = (pa_["mode"] == "regular").to_numpy()
        diffs.append((pb["p_hvac_kw"] - pa_["p_hvac_kw"]).to_numpy()[running])
    diff = np.concatenate(diffs)
    assert len(diff) > 600 and abs(np.median(diff) - 1.0) < 0.05
