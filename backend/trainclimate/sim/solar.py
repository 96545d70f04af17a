"""Solar geometry (through pvlib) and the paper's projections of irradiance on the train.

The paper (Section III.A) writes the irradiance on the roof as ``Q_Gt = |Q_G cos α|`` and on the
side as ``Q_Gs = |Q_G sin α sin(β − θ)|`` with α "the solar elevation angle", β the solar azimuth
and θ the train's heading. Those projections are physical only when α is the solar **zenith**
angle (sun overhead → everything on the roof, nothing on the sides), so the functions here take
the zenith angle and say so (DESIGN.md, modelling notes). G is the global horizontal irradiance.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pvlib


def _check_tz(times: pd.DatetimeIndex) -> None:
    if getattr(times, "tz", None) is None:
        raise ValueError("times must be timezone-aware")


def solar_position(
    times: pd.DatetimeIndex, latitude_deg: float, longitude_deg: float, altitude_m: float = 400.0
) -> pd.DataFrame:
    """Apparent solar zenith, elevation and azimuth (degrees; azimuth clockwise from north).

    ``times`` tz-aware; latitude/longitude in degrees (north, east positive); altitude in m.
    Uses :func:`pvlib.solarposition.get_solarposition` (NREL SPA, Reda & Andreas 2004).
    """
    _check_tz(times)
    sp = pvlib.solarposition.get_solarposition(
        times, latitude_deg, longitude_deg, altitude=altitude_m
    )
    return pd.DataFrame(
        {
            "zenith_deg": sp["apparent_zenith"].to_numpy(),
            "elevation_deg": sp["apparent_elevation"].to_numpy(),
            "azimuth_deg": sp["azimuth"].to_numpy(),
        },
        index=times,
    )


def clear_sky_ghi(
    times: pd.DatetimeIndex, latitude_deg: float, longitude_deg: float, altitude_m: float = 400.0
) -> np.ndarray:
    """Clear-sky global horizontal irradiance in W/m² (Ineichen & Perez 2002 model in pvlib,
    Linke turbidity from pvlib's shipped monthly climatology)."""
    _check_tz(times)
    loc = pvlib.location.Location(latitude_deg, longitude_deg, altitude=altitude_m)
    return loc.get_clearsky(times, model="ineichen")["ghi"].to_numpy()


def roof_irradiance(ghi_w_m2, zenith_deg) -> np.ndarray:
    """Q_Gt = |G cos(zenith)| in W/m² (paper, Section III.A, with α read as the zenith angle).

    ``ghi_w_m2`` global horizontal irradiance (W/m²), ``zenith_deg`` solar zenith (degrees); any
    broadcastable shapes. Zero when the sun is below the horizon or G ≤ 0.
    """
    g = np.asarray(ghi_w_m2, dtype=float)
    z = np.asarray(zenith_deg, dtype=float)
    up = (z < 90.0) & (g > 0.0)
    return np.where(up, np.abs(g * np.cos(np.radians(z))), 0.0)


def side_irradiance(ghi_w_m2, zenith_deg, azimuth_deg, heading_deg) -> np.ndarray:
    """Q_Gs = |G sin(zenith) sin(β − θ)| in W/m² on the sunlit side of the train.

    β solar azimuth and θ train heading, both degrees clockwise from north; zenith in degrees;
    G in W/m²; any broadcastable shapes. Zero below the horizon, with the sun straight ahead or
    behind (β = θ) and with G ≤ 0.
    """
    g = np.asarray(ghi_w_m2, dtype=float)
    z = np.asarray(zenith_deg, dtype=float)
    rel = np.radians(np.asarray(azimuth_deg, dtype=float) - np.asarray(heading_deg, dtype=float))
    up = (z < 90.0) & (g > 0.0)
    return np.where(up, np.abs(g * np.sin(np.radians(z)) * np.sin(rel)), 0.0)
