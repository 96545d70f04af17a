"""Solar geometry (through pvlib) and the paper's projections of irradiance on the train.

The paper (Sections II.C.4 and III.B) writes the irradiance on the roof as ``Q_Gt = |Q_G cos α|``
and on the side as ``Q_Gs = |Q_G sin α sin(β − θ)|`` with α "the solar elevation angle", β the
solar azimuth and θ the train's heading. Those projections are physical only when α is the solar
**zenith** angle (sun overhead → everything on the roof, nothing on the sides), so the functions
here take the zenith angle and say so (docs/model.md). G is the global horizontal irradiance.
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
    """Apparent solar zenith, elevation and azimuth at a site.

    Uses :func:`pvlib.solarposition.get_solarposition` (NREL SPA).

    Parameters
    ----------
    times : pandas.DatetimeIndex
        Timezone-aware times.
    latitude_deg, longitude_deg : float
        Site position, north and east positive. [°]
    altitude_m : float, default 400.0
        Site altitude above sea level. [m]

    Returns
    -------
    pandas.DataFrame
        Indexed by ``times``, columns ``zenith_deg``, ``elevation_deg`` and ``azimuth_deg``
        (clockwise from north). [°]

    Raises
    ------
    ValueError
        If ``times`` is not timezone-aware.

    References
    ----------
    .. [1] I. Reda and A. Andreas, Solar position algorithm for solar radiation applications,
       Solar Energy 76(5), 2004.
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
    """Clear-sky global horizontal irradiance at a site.

    The Ineichen & Perez model in pvlib, with the Linke turbidity from pvlib's shipped monthly
    climatology.

    Parameters
    ----------
    times, latitude_deg, longitude_deg, altitude_m
        The timezone-aware times and the site (°, °, m), as in :func:`solar_position`.

    Returns
    -------
    numpy.ndarray of shape (len(times),)
        Clear-sky GHI. [W/m²]

    Raises
    ------
    ValueError
        If ``times`` is naive (has no timezone).

    References
    ----------
    .. [1] P. Ineichen and R. Perez, A new airmass independent formulation for the Linke
       turbidity coefficient, Solar Energy 73(3), 2002.
    """
    _check_tz(times)
    loc = pvlib.location.Location(latitude_deg, longitude_deg, altitude=altitude_m)
    return loc.get_clearsky(times, model="ineichen")["ghi"].to_numpy()


def _lit(ghi_w_m2, zenith_deg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """G and the zenith angle as float arrays, and where the sun is up and G > 0."""
    g = np.asarray(ghi_w_m2, dtype=float)
    z = np.asarray(zenith_deg, dtype=float)
    return g, z, (z < 90.0) & (g > 0.0)


def roof_irradiance(ghi_w_m2, zenith_deg) -> np.ndarray:
    """Irradiance projected on the roof, Q_Gt = |G cos(zenith)|.

    The paper's α is read as the zenith angle (see the module docstring).

    Parameters
    ----------
    ghi_w_m2 : array-like
        Global horizontal irradiance G. [W/m²]
    zenith_deg : array-like
        Solar zenith angle, broadcastable against ``ghi_w_m2``. [°]

    Returns
    -------
    numpy.ndarray
        Q_Gt, the broadcast shape; zero when the sun is below the horizon or G ≤ 0. [W/m²]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Sections II.C.4 and III.B.
    """
    g, z, up = _lit(ghi_w_m2, zenith_deg)
    return np.where(up, np.abs(g * np.cos(np.radians(z))), 0.0)


def side_irradiance(ghi_w_m2, zenith_deg, azimuth_deg, heading_deg) -> np.ndarray:
    """Irradiance projected on the sunlit side of the train, Q_Gs = |G sin(zenith) sin(β − θ)|.

    Parameters
    ----------
    ghi_w_m2, zenith_deg : array-like
        G [W/m²] and the solar zenith angle [°], as in :func:`roof_irradiance`.
    azimuth_deg : array-like
        Solar azimuth β, clockwise from north. [°]
    heading_deg : array-like
        Train heading θ, clockwise from north. [°]

    Returns
    -------
    numpy.ndarray
        Q_Gs, the broadcast shape of the inputs; zero below the horizon, with the sun straight
        ahead or behind (β = θ) and with G ≤ 0. [W/m²]

    References
    ----------
    .. [1] Aboudonia et al., A Data-driven Predictive Control Architecture for Train Thermal
       Energy Management, Sections II.C.4 and III.B.
    """
    g, z, up = _lit(ghi_w_m2, zenith_deg)
    rel = np.radians(np.asarray(azimuth_deg, dtype=float) - np.asarray(heading_deg, dtype=float))
    return np.where(up, np.abs(g * np.sin(np.radians(z)) * np.sin(rel)), 0.0)
