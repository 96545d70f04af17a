import numpy as np
import pandas as pd
import pytest

from trainclimate.sim.solar import (
    clear_sky_ghi,
    roof_irradiance,
    side_irradiance,
    solar_position,
)

ZURICH = (47.3779, 8.5403, 408.0)


def noon(day):
    t = pd.date_range(f"{day} 10:00", f"{day} 14:00", freq="1min", tz="Europe/Zurich")
    sp = solar_position(t, *ZURICH)
    return sp.loc[sp["elevation_deg"].idxmax()]


def test_solar_noon_elevation_in_zurich():
    assert noon("2024-06-21")["elevation_deg"] == pytest.approx(90 - 47.38 + 23.44, abs=1.0)
    assert noon("2024-12-21")["elevation_deg"] == pytest.approx(90 - 47.38 - 23.44, abs=1.0)
    assert noon("2024-06-21")["azimuth_deg"] == pytest.approx(180.0, abs=2.0)


def test_naive_times_are_rejected():
    with pytest.raises(ValueError, match="timezone-aware"):
        solar_position(pd.date_range("2024-06-21", periods=3, freq="h"), *ZURICH)


def test_clear_sky_ghi():
    t = pd.DatetimeIndex(["2024-06-21 13:30", "2024-06-21 02:00"]).tz_localize("Europe/Zurich")
    ghi = clear_sky_ghi(t, *ZURICH)
    assert 800 <= ghi[0] <= 1000
    assert ghi[1] == 0.0


def test_projections():
    g = 800.0
    # sun at the zenith: all on the roof, nothing on the side
    assert roof_irradiance(g, 0.0) == pytest.approx(g)
    assert side_irradiance(g, 0.0, 180.0, 90.0) == pytest.approx(0.0, abs=1e-9)
    # low sun abeam of the train
    assert side_irradiance(g, 80.0, 180.0, 90.0) == pytest.approx(g * np.sin(np.radians(80)))
    assert side_irradiance(g, 80.0, 0.0, 90.0) == pytest.approx(g * np.sin(np.radians(80)))
    # sun straight ahead or behind
    assert side_irradiance(g, 60.0, 90.0, 90.0) == pytest.approx(0.0, abs=1e-9)
    assert side_irradiance(g, 60.0, 270.0, 90.0) == pytest.approx(0.0, abs=1e-9)
    # below the horizon or no irradiance: zero
    assert roof_irradiance(g, 95.0) == 0.0 and side_irradiance(g, 95.0, 180, 90) == 0.0
    assert roof_irradiance(-5.0, 30.0) == 0.0


def test_projections_broadcast():
    g = np.full((4, 3), 500.0)
    z = np.linspace(10, 80, 4)[:, None]
    heading = np.array([0.0, 90.0, 180.0])
    assert side_irradiance(g, z, 135.0, heading).shape == (4, 3)
    assert roof_irradiance(g, z).shape == (4, 3)
    # the roof and side components never exceed G
    assert np.all(
        roof_irradiance(g, z) ** 2 + side_irradiance(g, z, 135.0, heading) ** 2 <= 500.0**2 + 1e-6
    )
