"""The Trajectory type: shapes checked, Parquet round trip exact, files byte-identical."""

import numpy as np
import pandas as pd
import pytest

from trainclimate.data.trajectory import (
    D_NAMES,
    Trajectory,
    TrajectoryWriter,
    iter_trajectories,
    read_trajectories,
)


def trajectory(n=12, *, start="2022-03-27 00:55", tz="UTC", step=1, coach="44A", seed=0):
    rng = np.random.default_rng(seed)
    return Trajectory(
        time=pd.date_range(start, periods=n, freq=f"{step}min", tz=tz),
        y=rng.normal(21.0, 1.0, (n, 3)),
        u=rng.normal(22.0, 0.5, (n, 1)),
        d=rng.normal(0.0, 100.0, (n, 5)),
        campaign="winter-spring",
        train=coach[:-1],
        coach=coach,
        sampling_min=step,
    )


def test_parquet_round_trip_keeps_values_times_and_metadata(tmp_path):
    written = [
        trajectory(12, coach="44A", seed=1),
        # local times across the DST change come back as the same instants in UTC
        trajectory(7, start="2022-03-27 01:50", tz="Europe/Zurich", step=5, coach="66A", seed=2),
        trajectory(3, coach="124A", seed=3),
    ]
    path = tmp_path / "t.parquet"
    with TrajectoryWriter(path) as writer:
        writer.write(written[:2])
        writer.write([])
        writer.write(written[2:])
    assert (writer.count, writer.points) == (3, 22)
    back = read_trajectories(path)
    assert [t.id for t in back] == [t.id for t in written]
    assert back[1].id == "winter-spring/66A/20220327T0050"
    for a, b in zip(written, back, strict=True):
        assert str(b.time.tz) == "UTC"
        assert (b.time == a.time).all()
        np.testing.assert_array_equal(b.y, a.y)
        np.testing.assert_array_equal(b.u, a.u)
        np.testing.assert_array_equal(b.d, a.d)
        assert (b.campaign, b.train, b.coach, b.sampling_min) == (
            a.campaign,
            a.train,
            a.coach,
            a.sampling_min,
        )
    assert back[1].time[2] - back[1].time[1] == pd.Timedelta("5min")
    chosen = list(iter_trajectories(path, filters=lambda campaign, coach: coach == "66A"))
    assert [t.id for t in chosen] == [written[1].id]


def test_the_long_format_has_one_column_per_signal():
    frame = trajectory(4).frame()
    assert len(frame) == 4 and frame["traj_id"].nunique() == 1
    for j, name in enumerate(D_NAMES):
        np.testing.assert_array_equal(frame[name], trajectory(4).d[:, j])


def test_same_trajectories_write_byte_identical_files(tmp_path):
    for name in ("a", "b"):
        with TrajectoryWriter(tmp_path / f"{name}.parquet") as writer:
            writer.write([trajectory(30, seed=5), trajectory(10, coach="66A", seed=6)])
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"y": np.zeros((5, 2))}, r"y must have shape \(5, 3\)"),
        ({"y": np.zeros((4, 3))}, r"y must have shape \(5, 3\)"),
        ({"u": np.zeros(5)}, r"u must have shape \(5, 1\)"),
        ({"d": np.zeros((5, 4))}, r"d must have shape \(5, 5\)"),
        ({"time": pd.date_range("2022-03-01", periods=5, freq="1min")}, "timezone-aware"),
    ],
)
def test_wrong_shapes_and_naive_times_raise(change, message):
    good = {
        "time": pd.date_range("2022-03-01", periods=5, freq="1min", tz="UTC"),
        "y": np.zeros((5, 3)),
        "u": np.zeros((5, 1)),
        "d": np.zeros((5, 5)),
    }
    Trajectory(**good)
    with pytest.raises(ValueError, match=message):
        Trajectory(**{**good, **change})
