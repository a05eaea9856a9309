"""Every vendor's RPC file read by content (issue 35, item 1; issue 34, "one format table").

The references: rpcm's own parsers (``rpcm.rpc_from_rpc_file``, BSD, a test-only peer) on the real
files of ``../shared/data/satellite`` (IKONOS text, Pleiades DIMAP v2, WorldView-3 ISD XML), GDAL's
(rasterio's) reading of the ``.RPB`` / ``_RPC.TXT`` / GeoTIFF tags photax writes, and files made
here from the real files' coefficients (DIMAP v3, a GeoEye-style ISD, rpcm/s2p JSON, a VRT) whose
truth is the file they were made from.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
import types

import numpy as np
import pytest
from conftest import ROOT, shared_file

import photax as ptx
from photax.errors import MalformedFileError, NoEntryError, UnsupportedFormatError
from photax.io.satellite import read_rpc, rpc_format, rpc_images, write_rpc

rasterio = pytest.importorskip("rasterio")

SHARED = {"rpc_IKONOS.txt": "rpc-txt", "rpc_PLEIADES.xml": "dimap", "rpc_WV3.xml": "maxar-xml"}


@pytest.fixture(scope="module")
def rpcm():
    """rpcm's ``rpc_model`` module.  rpcm is installed without its dependencies (``pip install
    --no-deps rpcm``: its ``__init__`` imports geojson and srtm4, for footprints photax does not compare);
    its parsers and models need only numpy, pyproj and rasterio, so they are loaded without the
    package's ``__init__`` when that fails."""
    try:
        import rpcm.rpc_model as model

        return model
    except ImportError:
        pass
    spec = importlib.util.find_spec("rpcm")
    if spec is None:
        pytest.skip("rpcm is not installed (pip install --no-deps rpcm)")
    package = types.ModuleType("rpcm")  # the package without its __init__ (geojson, srtm4)
    package.__path__ = list(spec.submodule_search_locations)
    sys.modules["rpcm"] = package
    return importlib.import_module("rpcm.rpc_model")


def _grid(cam, n=7, layers=5):
    """Ground points over the RPC's validity volume (offsets +- scales, 0.9 of it: the corners of a
    real scene's box are far outside its image)."""
    o, s = np.asarray(cam.offsets), np.asarray(cam.scales)
    axes = np.meshgrid(np.linspace(-0.9, 0.9, n), np.linspace(-0.9, 0.9, n), np.linspace(-1, 1, layers), indexing="ij")
    return np.stack(axes, -1).reshape(-1, 3) * s[:3] + o[:3]


def _rpcm_projection(model, ground):
    c, r = model.projection(ground[:, 0], ground[:, 1], ground[:, 2])
    return np.column_stack([c, r])


@pytest.mark.parametrize("name", list(SHARED))
def test_shared_files_equal_rpcm_and_renamed_copies(name, rpcm, tmp_path):
    """Each real file: its family by content, its projection equal to rpcm's parse to 1e-9 px over the
    validity volume; the same bytes under an odd name without a suffix read the same."""
    path = shared_file(f"satellite/{name}")
    assert rpc_format(path) == SHARED[name]
    cam = read_rpc(path)
    ground = _grid(cam)
    ours = np.asarray(cam(ground))
    ref = _rpcm_projection(rpcm.rpc_from_rpc_file(str(path)), ground)
    assert np.max(np.abs(ours - ref)) <= 1e-9
    # the grid does cover the image (not a degenerate test)
    assert np.ptp(ours[:, 0]) > np.asarray(cam.scales)[3] and np.ptp(ours[:, 1]) > np.asarray(cam.scales)[4]
    odd = tmp_path / "Scene metadata (copy)"
    shutil.copyfile(path, odd)
    assert rpc_format(odd) == SHARED[name]
    again = read_rpc(odd)
    np.testing.assert_array_equal(np.asarray(again(ground)), ours)
    assert (again.direct is None) == (cam.direct is None)
    assert ptx.read_rpc is read_rpc  # the top-level name is this reader


def test_old_import_path_still_reads():
    from photax.rpc import read_rpc as old

    assert old is read_rpc


def test_pleiades_direct_model_is_rpcm_localization_and_differs_from_newton(rpcm):
    """DIMAP's direct (image -> ground) model is kept and used by default, as rpcm's localization;
    Newton's inverse of the ground -> image model is there on request, and the two differ by the
    vendor's fit (about a millimetre: printed)."""
    path = shared_file("satellite/rpc_PLEIADES.xml")
    cam, ref = read_rpc(path), rpcm.rpc_from_rpc_file(str(path))
    assert cam.direct is not None and cam.localization == "direct" and cam.localizes_directly
    ground = _grid(cam)
    pixel = np.asarray(cam(ground))
    direct = np.asarray(cam.to_ground(pixel, ground[:, 2]))
    lon, lat = ref.localization(pixel[:, 0], pixel[:, 1], ground[:, 2])
    assert np.max(np.abs(direct - np.column_stack([lon, lat]))) <= 1e-12  # deg, ~0.1 um
    newton = np.asarray(cam.to_ground(pixel, ground[:, 2], method="newton"))
    np.testing.assert_allclose(newton, ground[:, :2], rtol=0, atol=1e-11)  # Newton inverts the projection
    assert np.array_equal(np.asarray(cam.with_localization("newton").localize(pixel, ground[:, 2])), newton)
    import pyproj

    _, _, metres = pyproj.Geod(ellps="WGS84").inv(direct[:, 0], direct[:, 1], newton[:, 0], newton[:, 1])
    print(f"Pleiades direct vs Newton: median {1e3 * np.median(metres):.2f} mm, max {1e3 * metres.max():.2f} mm")
    assert 1e-5 < np.median(metres) and metres.max() < 0.01  # not the same model, and within a centimetre
    # the sensor protocol's jittable inverse uses the direct model too
    ll, ok = cam.invert(pixel, ground[:, 2])
    assert np.all(np.asarray(ok)) and np.array_equal(np.asarray(ll), direct)
    # a refinement keeps it
    refined = ptx.refine_rpc(cam, ground[:5], pixel[:5] + [2.0, -1.0], "shift")
    assert refined.camera.direct is not None
    back = np.asarray(refined.camera.to_ground(pixel[:5] + [2.0, -1.0], ground[:5, 2]))
    np.testing.assert_allclose(back, direct[:5], rtol=0, atol=1e-9)


def _dimap_v3(v2_text: str) -> str:
    """A Pleiades Neo (DIMAP v3) file made from a v2 one: ``GroundtoImage_Values`` /
    ``ImagetoGround_Values`` with LON_/LAT_ names, 0-based offsets said by the validity domain."""
    import re
    from xml.etree import ElementTree as ET

    root = ET.fromstring(v2_text)
    grfm = root.find("Rational_Function_Model/Global_RFM")
    direct, inverse = grfm.find("Direct_Model"), grfm.find("Inverse_Model")
    direct.tag, inverse.tag = "ImagetoGround_Values", "GroundtoImage_Values"
    for el in direct:
        el.tag = re.sub(r"^SAMP_", "LON_", re.sub(r"^LINE_", "LAT_", el.tag))
    validity = grfm.find("RFM_Validity")
    domain = ET.SubElement(validity, "ImagetoGround_Validity_Domain")
    for tag, value in (("FIRST_ROW", "0"), ("FIRST_COL", "0")):
        ET.SubElement(domain, tag).text = value
    for tag in ("LINE_OFF", "SAMP_OFF"):
        el = validity.find(tag)
        el.text = repr(float(el.text) - 1.0)
    root.find("Metadata_Identification/METADATA_PROFILE").text = "PNEO_SENSOR"
    return ET.tostring(root, encoding="unicode")


def test_dimap_v3_and_main_dim_file(tmp_path):
    path = shared_file("satellite/rpc_PLEIADES.xml")
    v2 = read_rpc(path)
    v3_path = tmp_path / "RPC_PNEO"
    v3_path.write_text(_dimap_v3(path.read_text()))
    assert rpc_format(v3_path) == "dimap"
    v3 = read_rpc(v3_path)
    ground = _grid(v2)
    np.testing.assert_allclose(np.asarray(v3(ground)), np.asarray(v2(ground)), rtol=0, atol=1e-9)
    pixel = np.asarray(v2(ground))
    np.testing.assert_allclose(
        np.asarray(v3.to_ground(pixel, ground[:, 2])), np.asarray(v2.to_ground(pixel, ground[:, 2])), atol=1e-12
    )
    # a main DIM_*.XML names its RPC file: followed
    (tmp_path / "RPC_PHR1A_P_001.XML").write_bytes(path.read_bytes())
    (tmp_path / "DIM_PHR1A_P_001.XML").write_text(
        '<?xml version="1.0"?>\n<Dimap_Document><Geoposition><Geoposition_Models><Rational_Function_Model>'
        '<COMPONENT_PATH href="RPC_PHR1A_P_001.XML"/></Rational_Function_Model></Geoposition_Models></Geoposition>'
        "</Dimap_Document>\n"
    )
    main = read_rpc(tmp_path / "DIM_PHR1A_P_001.XML")
    np.testing.assert_array_equal(np.asarray(main(ground)), np.asarray(v2(ground)))
    (tmp_path / "RPC_PHR1A_P_001.XML").unlink()
    with pytest.raises(MalformedFileError, match=r"names its RPC file 'RPC_PHR1A_P_001.XML', which is not there"):
        read_rpc(tmp_path / "DIM_PHR1A_P_001.XML")


def _isd(cam, satid="GE01") -> str:
    """A DigitalGlobe ISD (``<isd><RPB><IMAGE>``, GeoEye / QuickBird style) of ``cam``'s numbers."""
    o, s = np.asarray(cam.offsets), np.asarray(cam.scales)
    tags = ("LONGOFFSET", "LATOFFSET", "HEIGHTOFFSET", "SAMPOFFSET", "LINEOFFSET")
    scales = ("LONGSCALE", "LATSCALE", "HEIGHTSCALE", "SAMPSCALE", "LINESCALE")
    body = "".join(f"<{t}>{v!r}</{t}>" for t, v in zip(tags, o.tolist(), strict=True))
    body += "".join(f"<{t}>{v!r}</{t}>" for t, v in zip(scales, s.tolist(), strict=True))
    for tag, row in zip(("LINENUMCOEF", "LINEDENCOEF", "SAMPNUMCOEF", "SAMPDENCOEF"), np.asarray(cam.coefficients)):
        body += f"<{tag}List><{tag}>{' '.join(repr(float(c)) for c in row)}</{tag}></{tag}List>"
    return (
        f'<?xml version="1.0" encoding="UTF-8"?>\n<isd><IMD><IMAGE><SATID>{satid}</SATID></IMAGE></IMD>\n'
        f"<RPB><SATID>{satid}</SATID><IMAGE><ERRBIAS>1.0</ERRBIAS>\n{body}\n</IMAGE></RPB></isd>\n"
    )


def test_geoeye_style_isd_and_rpcm_json(rpcm, tmp_path):
    """An ISD XML and rpcm's / s2p's JSON made of the IKONOS file's numbers read as the text file."""
    path = shared_file("satellite/rpc_IKONOS.txt")
    cam, ref = read_rpc(path), rpcm.rpc_from_rpc_file(str(path))
    ground = _grid(cam)
    truth = _rpcm_projection(ref, ground)
    isd = tmp_path / "16MAY05GE01.XML"
    isd.write_text(_isd(cam))
    assert rpc_format(isd) == "maxar-xml"
    assert np.max(np.abs(np.asarray(read_rpc(isd)(ground)) - truth)) <= 1e-9
    js = tmp_path / "rpc.json"
    js.write_text(json.dumps(ref.__dict__))
    assert rpc_format(js) == "rpcm-json" and rpc_images(js) is None
    assert np.max(np.abs(np.asarray(read_rpc(js)(ground)) - truth)) <= 1e-9
    upper = tmp_path / "gdal_keys.json"
    upper.write_text(json.dumps(ref.to_geotiff_dict()))
    assert np.max(np.abs(np.asarray(read_rpc(upper)(ground)) - truth)) <= 1e-9
    s2p = tmp_path / "config.json"
    shifted = dict(ref.__dict__, col_offset=ref.col_offset + 10.0)
    s2p.write_text(json.dumps({"out_dir": "x", "images": [{"img": "a/im1.tif", "rpc": ref.__dict__},
                                                           {"img": "a/im2.tif", "rpc": shifted}]}))  # fmt: skip
    assert rpc_images(s2p) == ("im1.tif", "im2.tif")
    d = np.asarray(read_rpc(s2p, "im2.tif")(ground)) - np.asarray(read_rpc(s2p, "im1.tif")(ground))
    np.testing.assert_allclose(d, np.broadcast_to([10.0, 0.0], d.shape), atol=1e-9)
    with pytest.raises(MalformedFileError, match=r"holds 2 images \('im1.tif', 'im2.tif'\): pass image="):
        read_rpc(s2p)
    with pytest.raises(NoEntryError, match="no entry 'im3.tif'"):
        read_rpc(s2p, "im3.tif")


def test_orthority_yaml_by_content(tmp_path):
    yaml_path = shared_file("orthority/rpc/rpc_param.yaml")
    odd = tmp_path / "rpcs_for_the_scene.txt"
    shutil.copyfile(yaml_path, odd)
    assert rpc_format(odd) == "orthority" and rpc_images(odd) == ("qb2_basic1b.tif",)
    a, b = read_rpc(yaml_path), read_rpc(odd)
    ground = _grid(a)
    np.testing.assert_array_equal(np.asarray(a(ground)), np.asarray(b(ground)))
    assert a.image_size == b.image_size is not None


def _blank_tif(path, width=16, height=12, **profile):
    """A small image without georeferencing (a satellite scene's raw raster)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(
            path, "w", driver="GTiff", width=width, height=height, count=1, dtype="uint8", **profile
        ) as d:
            d.write(np.zeros((1, height, width), np.uint8))
    return path


@pytest.mark.parametrize("name", list(SHARED))
@pytest.mark.parametrize("fmt, side", [("rpc-txt", "_RPC.TXT"), ("rpb", ".RPB")])
def test_text_writers_round_trip_and_gdal_reads_them(name, fmt, side, tmp_path, rpcm):
    """write_rpc -> read_rpc gives the same projection; GDAL finds the file beside an image and reads
    the same numbers; rpcm reads the KEY: value text (with the direct model, as its localization)."""
    cam = read_rpc(shared_file(f"satellite/{name}"))
    ground = _grid(cam)
    out = write_rpc(cam, tmp_path / f"out{side}", fmt)
    assert rpc_format(out) == fmt
    back = read_rpc(out)
    np.testing.assert_allclose(np.asarray(back(ground)), np.asarray(cam(ground)), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.coefficients, cam.coefficients)  # repr: float64 exactly
    import warnings

    image = _blank_tif(tmp_path / "im.tif")
    shutil.copyfile(out, tmp_path / f"im{side}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(image) as src:
            gdal = src.rpcs.to_dict()
    ours = cam.to_dict()
    for k, v in ours.items():
        np.testing.assert_array_equal(np.asarray(gdal[k], dtype=float), np.asarray(v), err_msg=k)
    if fmt == "rpc-txt":
        ref = rpcm.rpc_from_rpc_file(str(out))
        assert np.max(np.abs(_rpcm_projection(ref, ground) - np.asarray(cam(ground)))) <= 1e-9
        assert hasattr(ref, "lon_num") == (cam.direct is not None)
        if cam.direct is not None:
            pixel = np.asarray(cam(ground))
            lon, lat = ref.localization(pixel[:, 0], pixel[:, 1], ground[:, 2])
            np.testing.assert_allclose(np.asarray(back.to_ground(pixel, ground[:, 2])), np.column_stack([lon, lat]),
                                       rtol=0, atol=1e-12)  # fmt: skip


def test_geotiff_tags_writer_and_refined_rpc(tmp_path):
    """A refined RPC written into a GeoTIFF's tags: GDAL's RPC transformer on the written tags gives the
    refined RPC's positions (a shift folded exactly into the offsets; an affine correction refitted)."""
    from rasterio.transform import RPCTransformer

    cam = read_rpc(shared_file("satellite/rpc_IKONOS.txt")).replace(image_size=(12668, 10248))
    ground = _grid(cam)
    truth = np.asarray(cam(ground))
    inside = np.all((truth >= 0) & (truth < [12668, 10248]), axis=1)
    refined = ptx.refine_rpc(cam, ground[inside][::7], truth[inside][::7] + [3.25, -1.5], "shift").camera
    tif = _blank_tif(tmp_path / "scene.tif")
    write_rpc(refined, tif, "geotiff")
    assert rpc_format(tif) == "raster"
    with rasterio.open(tif) as src, RPCTransformer(src.rpcs) as t:
        rows, cols = t.rowcol(ground[:, 0], ground[:, 1], zs=ground[:, 2], op=lambda x: x)
        assert src.width == 16  # the image is kept
    gdal = np.column_stack([cols, rows]) - 0.5  # GDAL counts from the pixel's corner, photax from its centre
    np.testing.assert_allclose(gdal, np.asarray(refined(ground)), rtol=0, atol=1e-6)
    np.testing.assert_allclose(gdal, truth + [3.25, -1.5], rtol=0, atol=1e-6)
    back = read_rpc(tif)
    np.testing.assert_allclose(np.asarray(back(ground)), np.asarray(refined(ground)), rtol=0, atol=1e-9)
    # an affine correction mixes the axes: refitted, within 1e-3 px of the refined model
    k = np.array([[1.0, 2e-5, -3e-5], [-2.0, 1e-5, 4e-5]])
    affine = cam.replace(correction=k)
    write_rpc(affine, tmp_path / "affine_RPC.TXT")
    fitted = read_rpc(tmp_path / "affine_RPC.TXT")
    inside = ground[np.all((np.asarray(affine(ground)) >= 0) & (np.asarray(affine(ground)) < [12668, 10248]), axis=1)]
    assert len(inside) > 50
    assert np.max(np.abs(np.asarray(fitted(inside)) - np.asarray(affine(inside)))) < 2e-3
    with pytest.raises(ValueError, match="rewrites the RPC tags of an existing GeoTIFF"):
        write_rpc(cam, tmp_path / "none.tif", "geotiff")
    with pytest.raises(ValueError, match="format: expected one of rpc-txt, rpb, geotiff"):
        write_rpc(cam, tmp_path / "x", "nitf")


def test_vrt_rpc_metadata(tmp_path):
    cam = read_rpc(shared_file("satellite/rpc_WV3.xml"))
    tif = _blank_tif(tmp_path / "src.tif", rpcs=rasterio.rpc.RPC(**cam.to_dict()))
    from rasterio.shutil import copy

    vrt = tmp_path / "scene.vrt"
    copy(tif, vrt, driver="VRT")
    assert "RPC" in vrt.read_text() and rpc_format(vrt) == "raster"
    ground = _grid(cam)
    np.testing.assert_allclose(np.asarray(read_rpc(vrt)(ground)), np.asarray(cam(ground)), rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "content",
    [b"", b"hello world\n", b"\x89PNG\r\n\x1a\n" + bytes(64), b"<?xml version='1.0'?><gpx></gpx>",
     b'{"type": "FeatureCollection"}', b"focal_length: 35\npixel_size: 0.004\n"],
)  # fmt: skip
def test_unknown_file_names_the_families(content, tmp_path):
    path = tmp_path / "thing_RPC.TXT"  # even a GDAL name does not make it one
    path.write_bytes(content)
    with pytest.raises(UnsupportedFormatError) as info:
        read_rpc(path)
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg
    for family in ("DIMAP", "Maxar ISD XML", "KEY: value", ".RPB", "orthority", "rpcm / s2p JSON", "GeoTIFF"):
        assert family in msg, (family, msg)
    assert isinstance(info.value, ValueError)
    with pytest.raises(UnsupportedFormatError):
        rpc_format(path)
    with pytest.raises(UnsupportedFormatError, match="push-broom camera file and the RPC families"):
        ptx.read_sensor(path)


def test_malformed_files_name_the_line_or_key(tmp_path):
    ikonos = shared_file("satellite/rpc_IKONOS.txt").read_text().splitlines()
    cases = {
        "missing": ("\n".join(ln for ln in ikonos if not ln.startswith("LAT_SCALE")), r": missing LAT_SCALE$"),
        "truncated": ("\n".join(ikonos[:45]), r": missing LINE_DEN_COEFF_16, LINE_DEN_COEFF_17, "),
        "bad number": ("\n".join(ln.replace("+00.06610000", "0.066l") for ln in ikonos), r", line 8: LAT_SCALE is not a number: '0.066l'"),
        "twice": ("\n".join([*ikonos, ikonos[3]]), r", line 93: LONG_OFF given twice \(first on line 4\)"),
        "infinite": ("\n".join(ln.replace("+1.221942364020734E+00", "1e999") for ln in ikonos), r", line 12: LINE_NUM_COEFF_2 is not finite"),
    }  # fmt: skip
    for name, (text, pattern) in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.txt"
        path.write_text(text)
        with pytest.raises(MalformedFileError, match=pattern) as info:
            read_rpc(path)
        assert str(info.value).startswith(str(path)), name
    pleiades = shared_file("satellite/rpc_PLEIADES.xml").read_text()
    xml_cases = {
        "no scale": (pleiades.replace("<LAT_SCALE>0.08714875721540594</LAT_SCALE>", ""), r"missing RFM_Validity/LAT_SCALE"),
        "bad coefficient": (pleiades.replace("<SAMP_NUM_COEFF_2>0.9982004051629711<", "<SAMP_NUM_COEFF_2>x<"),
                            r", line 17: Direct_Model/SAMP_NUM_COEFF_2 is not a number: 'x'"),
        "bad inverse": (pleiades.replace("<SAMP_NUM_COEFF_1>-0.002348990492619796<", "<SAMP_NUM_COEFF_1>nan<"),
                        r", line 100: Inverse_Model/SAMP_NUM_COEFF_1 is not finite"),
        "cut": (pleiades[:5000], r", line \d+: not well-formed XML"),
        "no model": (pleiades.replace("Inverse_Model>", "Other>"), r"without a Rational_Function_Model"),
        "v1": ('<?xml version="1.0"?>\n<Dimap_Document name="SPOT5"><Metadata_Id><METADATA_FORMAT version="1.1">DIMAP'
               "</METADATA_FORMAT></Metadata_Id></Dimap_Document>", r"DIMAP v1 \(SPOT 1-5, Formosat\) carries a physical"),
        "entity": (pleiades.replace("<Dimap_Document>", '<!DOCTYPE d [<!ENTITY a "aaaa">]><Dimap_Document>'), r"entity declaration"),
    }  # fmt: skip
    for name, (text, pattern) in xml_cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.xml"
        path.write_text(text)
        with pytest.raises(MalformedFileError, match=pattern):
            read_rpc(path)
    wv3 = shared_file("satellite/rpc_WV3.xml").read_text()
    path = tmp_path / "wv3.xml"
    path.write_text(wv3.replace("<LATSCALE>6.850000000000001e-02</LATSCALE>", "<LATSCALE>0</LATSCALE>"))
    with pytest.raises(MalformedFileError, match="zero scale RPB/IMAGE/LATSCALE"):
        read_rpc(path)
    path.write_text(wv3.replace("<RPB>", "<RPX>").replace("</RPB>", "</RPX>"))
    with pytest.raises(MalformedFileError, match="without an RPB/IMAGE block"):
        read_rpc(path)
    tif = tmp_path / "broken.tif"
    tif.write_bytes(b"II*\x00" + bytes(40))
    with pytest.raises(MalformedFileError, match="GDAL cannot read it"):
        read_rpc(tif)


def test_band_argument(tmp_path):
    path = shared_file("satellite/rpc_WV3.xml")
    ground = _grid(read_rpc(path))
    np.testing.assert_array_equal(np.asarray(read_rpc(path, band=1)(ground)), np.asarray(read_rpc(path)(ground)))
    with pytest.raises(MalformedFileError, match="holds one model for all bands"):
        read_rpc(path, band=2)


def test_read_sensor_by_content(tmp_path):
    import pyproj

    from photax.sensor import GroundSensor

    for name in SHARED:
        odd = tmp_path / name.upper().replace(".", "-")
        shutil.copyfile(shared_file(f"satellite/{name}"), odd)
        sensor = ptx.read_sensor(odd)
        assert isinstance(sensor, GroundSensor)
        cam = read_rpc(odd)
        lon, lat = (float(v) for v in np.asarray(cam.offsets)[:2])
        zone = int((lon + 180) // 6) + 1
        assert pyproj.CRS(sensor.crs) == pyproj.CRS.from_epsg(32600 + zone if lat >= 0 else 32700 + zone)
        ground = _grid(cam)
        np.testing.assert_array_equal(np.asarray(sensor.camera(ground)), np.asarray(cam(ground)))


def test_cli_ortho_reads_any_rpc_file(tmp_path, capsys):
    """``photax ortho IMAGE --camera <a WorldView XML under any name>``: an RPC ortho, not the frame
    camera's "--exterior is required"; the ortho lies where the RPC puts the image."""
    from photax.cli import main

    wv3 = tmp_path / "rpc_WV2"
    shutil.copyfile(shared_file("satellite/rpc_WV3.xml"), wv3)
    image = _blank_tif(tmp_path / "img.tif", width=40, height=30)
    out = tmp_path / "o.tif"
    args = ["ortho", str(image), "--camera", str(wv3), "--height", "53", "--resolution", "1", "--no-progress"]
    assert main([*args, "-o", str(out)]) == 0, capsys.readouterr().err
    cam = read_rpc(wv3)
    centre = np.asarray(cam.to_ground(np.array([[19.5, 14.5]]), 53.0))[0]
    import pyproj

    with rasterio.open(out) as src:
        x, y = pyproj.Transformer.from_crs("EPSG:4326", src.crs, always_xy=True).transform(*centre)
        left, bottom, right, top = src.bounds
    assert left < x < right and bottom < y < top
    garbage = tmp_path / "camera.xml"
    garbage.write_text("<?xml version='1.0'?><nothing/>")
    assert main([*args, "--camera", str(garbage), "-o", str(tmp_path / "p.tif")]) == 2
    err = capsys.readouterr().err
    assert "--exterior is required with a frame camera" in err and "is no RPC file photax reads" in err
    assert "DIMAP" in err
    broken = tmp_path / "RPC_broken.XML"
    text = shared_file("satellite/rpc_PLEIADES.xml").read_text()
    broken.write_text(text.replace("<LAT_SCALE>0.08714875721540594</LAT_SCALE>", ""))
    assert main([*args, "--camera", str(broken), "-o", str(tmp_path / "q.tif")]) == 2
    err = capsys.readouterr().err
    assert f"{broken}: missing RFM_Validity/LAT_SCALE" in err and err.count("\n") == 1, err


def test_docs_list_every_family():
    text = (ROOT / "docs" / "formats.md").read_text()
    from photax.io.satellite import FORMATS, WRITE_FORMATS

    for fmt in FORMATS:
        assert f"`{fmt.name}`" in text, fmt.name
    for name in WRITE_FORMATS:
        assert f"`{name}`" in text, name


@pytest.mark.parametrize("name", ["read_rpc", "write_rpc", "rpc_format", "read_sensor"])
def test_examples_run(name):
    """The Examples of the public entry points run (as tests/test_doctests.py runs the others')."""
    import doctest

    function = getattr(ptx, name)
    assert "\n    Examples:\n" in function.__doc__, name
    tests = doctest.DocTestFinder(recurse=False).find(function, name, globs={})
    assert sum(len(t.examples) for t in tests) >= 3
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)


def test_direct_model_on_a_dem_and_bad_choice():
    """Onto a DEM (GDAL's RPC_DEM iteration) the direct model is used too, and Newton on request; both
    land on the DEM's surface, a millimetre apart."""
    cam = read_rpc(shared_file("satellite/rpc_PLEIADES.xml"))
    lon, lat = (float(v) for v in np.asarray(cam.offsets)[:2])
    heights = np.add.outer(np.linspace(40.0, 90.0, 41), np.linspace(0.0, 30.0, 41))
    step = 0.3 / 40
    dem = ptx.DEM(heights, (step, 0.0, lon - 0.15, 0.0, -step, lat + 0.15))  # lon, lat grid (crs None)
    pixel = np.array([[1000.0, 2000.0], [20000.0, 18000.0], [39000.0, 35000.0]])
    direct, status = cam.to_ground_dem_status(pixel, dem)
    newton = cam.to_ground_dem(pixel, dem, method="newton")
    assert np.all(status == 0)
    on_dem = np.asarray(dem.height(direct[:, 0], direct[:, 1]))
    np.testing.assert_allclose(direct[:, 2], on_dem, atol=1e-5)
    assert 0 < np.max(np.abs(direct[:, :2] - newton[:, :2])) < 1e-7  # deg: ~1 cm
    np.testing.assert_allclose(np.asarray(cam(direct)), pixel, atol=0.01)  # the vendor's two fits agree
    with pytest.raises(ValueError, match="localization: expected 'direct' or 'newton', got 'exact'"):
        cam.with_localization("exact")
    with pytest.raises(ValueError, match="replace: no field colour"):
        cam.replace(colour=1)
