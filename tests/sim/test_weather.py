import numpy as np
import pandas as pd
import pytest

from trainclimate.sim.weather import (
    SITES,
    WeatherError,
    generate_weather,
    load_weather_csv,
    write_weather_csv,
)

ZRH = SITES["zurich"]


def week(month, seed=1, **kw):
    start = pd.Timestamp(f"2023-{month:02d}-10", tz="Europe/Zurich")
    return generate_weather(ZRH, start, start + pd.Timedelta(days=7), seed=seed, **kw)


def local(w):
    return pd.Series(w.t_amb_c, index=w.time.tz_convert("Europe/Zurich"))


def test_reproducible_by_seed():
    a, b, c = week(3, seed=5), week(3, seed=5), week(3, seed=6)
    np.testing.assert_array_equal(a.t_amb_c, b.t_amb_c)
    np.testing.assert_array_equal(a.ghi_w_m2, b.ghi_w_m2)
    assert not np.array_equal(a.t_amb_c, c.t_amb_c)


def test_seasonal_cycle():
    assert week(7).t_amb_c.mean() - week(1).t_amb_c.mean() > 12.0


def test_pinned_daily_extremes_and_afternoon_maximum():
    w = week(8, t_min_c=17.0, t_max_c=32.0)
    days = local(w).groupby(local(w).index.date)
    full = [d for _, d in days if len(d) == 144]
    for d in full:
        assert d.max() == pytest.approx(32.0, abs=0.5)
        assert d.min() == pytest.approx(17.0, abs=0.5)
        assert 13 <= d.idxmax().hour <= 17


def test_clouds_cut_irradiance():
    clear, overcast = week(6, cloud_cover=0.05), week(6, cloud_cover=0.95)
    # Kasten & Czeplak: 1 − 0.75 C^3.4 → overcast days get well under half the clear irradiation
    assert overcast.ghi_w_m2.sum() < 0.5 * clear.ghi_w_m2.sum()
    for w in (clear, overcast):
        assert np.all(w.ghi_w_m2 >= 0)
        night = w.time.tz_convert("Europe/Zurich").hour.isin([0, 1, 2, 23])
        assert np.all(w.ghi_w_m2[night] == 0)


def test_interpolation_and_span():
    w = week(3)
    t = pd.date_range(w.time[0], periods=10, freq="10s")
    t_amb, ghi = w.at(t)
    assert t_amb.shape == (10,) and np.all(np.isfinite(ghi))
    with pytest.raises(ValueError, match="weather covers"):
        w.at(pd.date_range(w.time[-1] + pd.Timedelta(hours=2), periods=3, freq="h"))


def test_csv_round_trip(tmp_path):
    w = week(3)
    path = tmp_path / "w.csv"
    write_weather_csv(w, path)
    r = load_weather_csv(path)
    assert (r.time == w.time).all()
    np.testing.assert_allclose(r.t_amb_c, w.t_amb_c)


GOOD = [("2023-07-10T10:00:00+02:00", "20.5", "300"), ("2023-07-10T10:30:00+02:00", "21", "350")]


@pytest.mark.parametrize(
    ("header", "rows", "needle"),
    [
        ("time,t_amb_c", [r[:2] for r in GOOD], "missing column 'ghi_w_m2'"),
        ("time,t_amb_c,ghi_w_m2", [("noon", "20", "1"), GOOD[1]], "row 1: unparseable time"),
        ("time,t_amb_c,ghi_w_m2", [("2023-07-10T10:00:00", "20", "1"), GOOD[1]], "no UTC offset"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[1], GOOD[0]], "not strictly increasing"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[0], GOOD[0]], "not strictly increasing"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[0], (GOOD[1][0], "nan", "1")], "row 2: t_amb_c is NaN"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[0], (GOOD[1][0], "", "1")], "row 2: t_amb_c is NaN"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[0], (GOOD[1][0], "20", "-4")], "ghi_w_m2 = -4 outside"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[0], (GOOD[1][0], "99", "1")], "t_amb_c = 99 outside"),
        ("time,t_amb_c,ghi_w_m2", [GOOD[0]], "at least 2 rows"),
    ],
)
def test_bad_csv_names_the_problem(tmp_path, header, rows, needle):
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([header, *(",".join(r) for r in rows)]) + "\n")
    with pytest.raises(WeatherError) as err:
        load_weather_csv(path)
    assert needle in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(WeatherError, match="not found"):
        load_weather_csv(tmp_path / "none.csv")
