"""Projections through pyproj: coordinates, meridian convergence sign and scale factor by finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from georef.frames.mapping import CRSChoiceError, MapProjection


@pytest.mark.parametrize("crs, lat, lon", [("EPSG:3765", 45.0, 16.0), ("EPSG:3765", 44.0, 18.9),
                                           ("EPSG:32633", 44.05, 15.62), ("EPSG:32633", 60.0, 9.5)])
def test_convergence_and_scale_by_finite_differences(crs, lat, lon):
    proj = MapProjection(crs)
    convergence, scale = proj.convergence_and_scale(lat, lon)
    d = 1e-5
    e0, n0 = proj.forward(lat - d, lon)
    e1, n1 = proj.forward(lat + d, lon)
    grid_azimuth_of_north = np.degrees(np.arctan2(e1 - e0, n1 - n0))
    # a true azimuth alpha has grid azimuth alpha - convergence; true north has alpha = 0
    assert grid_azimuth_of_north == pytest.approx(-convergence, abs=1e-6)
    from georef.frames import radii_of_curvature

    M, _ = radii_of_curvature(np.radians(lat))
    ground = M * np.radians(2 * d)
    assert np.hypot(e1 - e0, n1 - n0) / ground == pytest.approx(scale, abs=1e-6)


def test_htrs96_central_meridian_has_no_convergence():
    proj = MapProjection("EPSG:3765")
    convergence, scale = proj.convergence_and_scale(45.0, 16.5)
    assert convergence == pytest.approx(0.0, abs=1e-9)
    assert scale == pytest.approx(0.9999, abs=1e-6)
    easting, _ = proj.forward(45.0, 16.5)
    assert easting == pytest.approx(500000.0, abs=1e-6)


@pytest.mark.parametrize("name", ["EPSG:4326", "EPSG:999999", "not a crs"])
def test_unusable_crs_is_a_clear_error(name):
    with pytest.raises(CRSChoiceError, match="CRS"):
        MapProjection(name)
