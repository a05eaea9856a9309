"""photax.geo.utm_crs against pyproj's own CRS database (which UTM zones of WGS 84 hold a point)."""

import numpy as np
import pytest

from photax.errors import OutsideValidityError
from photax.geo import utm_crs


def test_utm_crs_is_the_zone_pyproj_says_holds_the_point():
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    rng = np.random.default_rng(3)
    lon = rng.uniform(-179.5, 179.5, 15)
    lat = rng.uniform(-79.5, 55.0, 15)  # south of Norway's and Svalbard's exceptions (which photax does not make)
    lon = np.where(np.abs((lon + 180) % 6 - 3) > 2.9, lon + 0.5, lon)  # not on a zone edge
    for x, y in zip(lon, lat):
        info = query_utm_crs_info(
            datum_name="WGS 84", area_of_interest=AreaOfInterest(float(x), float(y), float(x), float(y))
        )
        zones = {f"{i.auth_name}:{i.code}" for i in info if i.name.startswith("WGS 84 / UTM zone")}
        assert utm_crs(lon=float(x), lat=float(y)) in zones, (x, y, zones)


@pytest.mark.parametrize("lon, lat", [(10.0, 85.0), (10.0, -81.0), (181.0, 0.0), (float("nan"), 0.0)])
def test_no_utm_zone_is_a_typed_error(lon, lat):
    with pytest.raises(OutsideValidityError, match="no UTM zone"):
        utm_crs(lon, lat)
    with pytest.raises(ValueError):  # what it was
        utm_crs(lon, lat)
