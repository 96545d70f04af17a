"""``dataset build`` as users call it: Table I, a rebuild from raw, exit 2 on bad raw data."""

import json

import pytest

from helpers.cli import call, call_json
from trainclimate.data.trajectory import read_trajectories


@pytest.mark.slow  # generates raw logs and builds the dataset twice: ≈ 30 s
def test_dataset_build_prints_the_contract_keys_and_rebuilds_the_same_from_raw(capsys, tmp_path):
    # two coaches: on the first day coach 124B stands in the depot, 44B is in service
    out = tmp_path / "fleet"
    data = call_json(
        capsys, "dataset", "build", "--out", str(out), "--days", "1", "--coaches", "2",
        "--campaign", "summer",
    )  # fmt: skip
    assert [(r["campaign"], r["sampling_min"]) for r in data["table"]] == [
        ("summer", 1),
        ("summer", 5),
        ("summer", 10),
    ]
    for row in data["table"]:
        found = read_trajectories(out / f"trajectories_{row['sampling_min']}min.parquet")
        assert row["trajectories"] == len(found) >= 1
        assert row["mean_points"] == round(sum(map(len, found)) / len(found), 1)
        assert {(t.campaign, t.coach, t.sampling_min) for t in found} == {
            ("summer", "44B", row["sampling_min"])
        }
    for key in ("dropped_rows", "repaired_rows"):
        assert all(isinstance(v, int) and v >= 0 for v in data[key].values())
    # a summer day at 2 s carries every per-row and per-cell defect
    assert "duplicate" in data["dropped_rows"]
    assert {"missing", "out_of_range", "spike"} <= set(data["invalid_cells"])
    assert data["generated"] == {"files": 6, "rows": data["raw_rows"], "coach_days": 2}
    assert data["unreadable_files"] == [] and data["raw"] == str(out / "raw")
    assert json.loads((out / "dataset.json").read_text())["table"] == data["table"]

    again = call_json(
        capsys, "dataset", "build", "--raw", str(out / "raw"), "--out", str(tmp_path / "again")
    )
    assert "generated" not in again
    for key in ("table", "dropped_rows", "repaired_rows", "raw_rows", "coach_days"):
        assert again[key] == data[key]
    for step in (1, 5, 10):
        name = f"trajectories_{step}min.parquet"
        assert (tmp_path / "again" / name).read_bytes() == (out / name).read_bytes()


def unusable_raw(tmp_path, kind):
    raw = tmp_path / "raw"
    if kind == "missing":
        return raw
    raw.mkdir()
    if kind == "garbage":
        log = raw / "summer" / "hvac" / "124_124B_2023-07-04.csv"
        log.parent.mkdir(parents=True)
        log.write_bytes(bytes(range(256)) * 2)
        (raw / "summer" / "trips" / "124_124B_2023-07-04.csv").parent.mkdir(parents=True)
        (raw / "summer" / "trips" / "124_124B_2023-07-04.csv").write_text("Zug;Abfahrt\n")
        (raw / "notes.csv").write_text("not a fleet log\n")
    return raw


@pytest.mark.parametrize(
    ("kind", "needle"),
    [
        ("missing", "--raw: no such directory"),
        ("empty", "no raw log files under"),
        ("garbage", "no usable trajectory"),
    ],
)
def test_dataset_build_on_missing_empty_or_unusable_raw_exits_2(
    capsys, caplog, tmp_path, kind, needle
):
    raw = unusable_raw(tmp_path, kind)
    code, out, err = call(
        capsys, "dataset", "build", "--raw", str(raw), "--out", str(tmp_path / "o")
    )
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    errors = [line for line in lines if line.startswith("trainclimate: error:")]
    assert len(errors) == 1 and lines[-1] == errors[0] and needle in errors[0]
    assert all(line.startswith("trainclimate: warning:") for line in lines[:-1])
    if kind == "garbage":
        warned = caplog.text + err
        for name in ("hvac/124_124B_2023-07-04.csv", "trips/124_124B_2023-07-04.csv"):
            assert f"unreadable raw file {raw / 'summer' / name}" in warned


def test_dataset_build_rejects_zero_days(capsys, tmp_path):
    code, out, err = call(capsys, "dataset", "build", "--out", str(tmp_path), "--days", "0")
    assert code == 2 and out == "" and "--days and --coaches must be at least 1" in err


def test_summer_times_without_their_z_need_timezone(capsys, tmp_path):
    """A summer HVAC log re-saved without the times' Z: refused with the reason, read with
    --timezone (which the output states), an unknown zone a usage error."""
    raw = tmp_path / "raw"
    log = raw / "summer" / "hvac" / "124_124B_2023-07-04.csv"
    log.parent.mkdir(parents=True)
    header = "timestamp,hvac_mode,t_setpoint,t_room_upper,t_room_middle,t_room_lower,speed_mps\n"
    rows = [f"2023-07-04T05:{m:02d}:00,REGULAR,24.0,24.1,24.2,24.3,0.0\n" for m in range(60)]
    log.write_text(header + "".join(rows), encoding="utf-8")
    code, out, err = call(
        capsys, "dataset", "build", "--raw", str(raw), "--out", str(tmp_path / "o")
    )
    assert code == 2 and out == ""
    [line] = err.strip().splitlines()
    assert "124_124B_2023-07-04.csv" in line and "without a time zone" in line
    assert "--timezone" in line
    code, out, err = call(
        capsys, "dataset", "build", "--raw", str(raw), "--out", str(tmp_path / "o"),
        "--timezone", "Mars/Olympus",
    )  # fmt: skip
    assert code == 2 and "unknown time zone 'Mars/Olympus'" in err
    code, out, err = call(
        capsys, "dataset", "build", "--raw", str(raw), "--out", str(tmp_path / "o"),
        "--timezone", "Europe/Zurich", "--json",
    )  # fmt: skip
    # no weather and trips: nothing usable, but the times were read (not refused)
    assert code == 2 and "no usable trajectory" in err and "time zone" not in err


def test_coach_params_for_the_generator_are_checked_first(capsys, tmp_path):
    bad = tmp_path / "params.json"
    bad.write_text(json.dumps({"c_room_j_k": [90.0, 60.0, 105.0]}))  # kJ/K, not J/K
    code, out, err = call(
        capsys, "dataset", "build", "--out", str(tmp_path / "o"), "--coach-params", str(bad)
    )
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "c_room_j_k" in err and "J/K" in err
    code, out, err = call(
        capsys, "dataset", "build", "--out", str(tmp_path / "o"), "--raw", str(tmp_path),
        "--coach-params", str(bad),
    )  # fmt: skip
    assert code == 2 and "not with --raw" in err
