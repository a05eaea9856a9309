"""True orthophotos: z-buffer occlusion (photax.occlusion_mask) and the block's true ortho
(photax.true_ortho) on a synthetic block with a box building.

The truth is independent of the code under test: the images are ray-traced analytically in NumPy
(each pixel's ray cut with the ground plane and the box by the slab test, the nearer hit wins), the
reference visibility is marched along each cell's ray to the camera over the DSM (NumPy, bilinear
heights by scipy), and the hidden strip is the box's analytic shadow seen from the camera.
"""

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, binary_erosion, map_coordinates

import photax as ptx
from photax.collinearity import look_at

# The synthetic DSM covers the building's surroundings, not each oblique image's whole footprint: the
# orthos warn that it covers 59-66 % of the image (PartialDEMWarning), as they should; not what is tested.
pytestmark = pytest.mark.filterwarnings("ignore::photax.errors.PartialDEMWarning")

X0, Y0 = 500_000.0, 4_000_000.0  # UTM-like: code that forgets to reduce coordinates shows it
BOX = (-20.0, 20.0, -20.0, 20.0, 20.0)  # building: x0, x1, y0, y1 (local m), height
FLY = 150.0
ROOF, WALL = 0.9, 0.7
SIZE, FOCAL = (640, 480), 400.0


def ground_texture(x, y):
    """Smooth ground grey (local m), resolvable on 1 m cells; darker than the roof everywhere."""
    return 0.35 + 0.15 * np.sin(2 * np.pi * x / 7.0) * np.cos(2 * np.pi * y / 9.0)


def _slab(origin, direction, lo, hi):
    """Ray-box slab test: ``(t_near, t_far)`` per ray (t_near > t_far: a miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - origin) / direction
        t1 = (hi - origin) / direction
    tmin, tmax = np.minimum(t0, t1), np.maximum(t0, t1)
    tmin = np.where(np.isnan(tmin), -np.inf, tmin)
    tmax = np.where(np.isnan(tmax), np.inf, tmax)
    return tmin.max(axis=-1), tmax.min(axis=-1)


def _render(exterior, camera, ss=2):
    """The image: ray-traced ground plane and box, ``ss x ss`` samples per pixel averaged."""
    w, h = camera.image_size
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    cc, rr = np.meshgrid((np.arange(w)[:, None] + sub).ravel(), (np.arange(h)[:, None] + sub).ravel())
    img = np.asarray(camera.pixel_to_image(np.column_stack([cc.ravel(), rr.ravel()])))
    # Collinearity (docs/conventions.md): a camera-frame ray (x - x0, y - y0, -f); R from the
    # orientation's own points_in_camera at the unit vectors.
    c = np.asarray(exterior.position)
    rot = np.asarray(exterior.points_in_camera(c[None] + np.eye(3))).T  # columns R e_i
    xn = (img - np.asarray(camera.principal_point)) / float(camera.focal_length)
    d = np.column_stack([xn, -np.ones(len(xn))]) @ rot  # R^T d_cam, rows
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = c - [X0, Y0, 0]
    t_ground = -c[2] / d[:, 2]
    bx0, bx1, by0, by1, bh = BOX
    tn, tf = _slab(c[None], d, np.array([bx0, by0, 0.0]), np.array([bx1, by1, bh]))
    hit = (tn <= tf) & (tf > 0)
    p_ground = c + t_ground[:, None] * d
    grey = ground_texture(p_ground[:, 0], p_ground[:, 1])
    z_hit = c[2] + tn * d[:, 2]
    grey = np.where(hit, np.where(np.abs(z_hit - bh) < 1e-6, ROOF, WALL), grey)
    return grey.reshape(h, ss, w, ss).mean(axis=(1, 3))


@pytest.fixture(scope="module")
def block():
    camera = ptx.FrameCamera.from_pixels(FOCAL, SIZE)
    exteriors = [look_at(np.array([X0 + dx, Y0, FLY]), np.array([X0 + dx, Y0 + 1e-3, 0.0])) for dx in (-60.0, 60.0)]
    images = [_render(e, camera) for e in exteriors]
    # DSM: 1 m cells, 20 m on the box's cells, 0 elsewhere.
    half = 80
    xc = -half + np.arange(2 * half) + 0.5
    inside = lambda v, lo, hi: (v > lo) & (v < hi)  # noqa: E731
    heights = np.where(inside(xc[None], BOX[0], BOX[1]) & inside(-xc[:, None], BOX[2], BOX[3]), BOX[4], 0.0)
    dsm = ptx.DEM(heights, (1.0, 0.0, X0 - half, 0.0, -1.0, Y0 + half))
    grid = ptx.Grid((1.0, 0.0, X0 - 50, 0.0, -1.0, Y0 + 50), (100, 100))
    gx = -50 + np.arange(100) + 0.5
    gx, gy = np.meshgrid(gx, -gx)  # local cell centres
    return camera, exteriors, images, dsm, heights, grid, gx, gy


def _marched(exterior, heights, gx, gy, steps=600):
    """Reference visibility: march from each cell's surface point towards the camera over the
    bilinear DSM until the ray is above its highest point; hidden where the DSM rises above it."""
    c = np.asarray(exterior.position) - [X0, Y0, 0]
    z0 = map_coordinates(heights, [80 - gy - 0.5, gx + 80 - 0.5], order=1)
    top = heights.max()
    t_end = np.clip((top - z0) / (c[2] - z0), 0, 1)
    t = np.linspace(0, 1, steps)[1:, None, None] * t_end[None] + 1e-4
    x = gx + t * (c[0] - gx)
    y = gy + t * (c[1] - gy)
    z = z0 + t * (c[2] - z0)
    surface = map_coordinates(heights, [(80 - y - 0.5).ravel(), (x + 80 - 0.5).ravel()], order=1).reshape(x.shape)
    return np.any(surface > z + 1e-6, axis=0)


def _shadow(exterior, gx, gy):
    """Analytic hidden strip: ground cells (outside the box) whose segment to the camera cuts the box."""
    c = np.asarray(exterior.position) - [X0, Y0, 0]
    p = np.stack([gx, gy, np.zeros_like(gx)], axis=-1).reshape(-1, 3)
    d = c[None] - p
    bx0, bx1, by0, by1, bh = BOX
    tn, tf = _slab(p, d, np.array([bx0, by0, 0.0]), np.array([bx1, by1, bh]))
    footprint = (gx > bx0) & (gx < bx1) & (gy > by0) & (gy < by1)
    return ((tn <= tf) & (tf > 0) & (tn < 1)).reshape(gx.shape) & ~footprint


def test_mask_agrees_with_ray_marching(block):
    camera, exteriors, _, dsm, heights, grid, gx, gy = block
    for e in exteriors:
        mask = ptx.occlusion_mask(e, camera, dsm, grid)
        ref = _marched(e, heights, gx, gy)
        agree = np.mean(mask == ref)
        print(f"hidden {ref.sum()} cells (ray marching), z-buffer {mask.sum()}, agreement {agree:.4f}")
        assert ref.sum() > 300  # the building does hide a strip
        assert agree >= 0.99


def test_mark_is_the_hidden_strip(block):
    camera, exteriors, images, dsm, _, grid, gx, gy = block
    for e, img in zip(exteriors, images):
        ortho, _ = ptx.orthorectify(img, e, camera, dsm, grid, occlusion="mark")
        marked = np.isnan(ortho)
        strip = _shadow(e, gx, gy)
        assert strip.sum() > 300
        # exactly the analytic strip, +- 1 cell
        assert not np.any(marked & ~binary_dilation(strip))
        assert not np.any(binary_erosion(strip) & ~marked)


def test_true_ortho_has_no_ghosts(block):
    camera, exteriors, images, dsm, _, grid, gx, gy = block
    truth = ground_texture(gx, gy)
    footprint = (gx > BOX[0]) & (gx < BOX[1]) & (gy > BOX[2]) & (gy < BOX[3])
    near = binary_dilation(footprint, iterations=2)  # the edge cells the resampling blends with the roof
    plain, _ = ptx.orthorectify(images[0], exteriors[0], camera, dsm, grid)
    info = {}
    true = ptx.true_ortho(images, exteriors, camera, dsm, grid, info=info)
    hidden = [_shadow(e, gx, gy) for e in exteriors]
    strip = hidden[0] & ~hidden[1] & ~near  # image 0's hidden strip that image 1 sees
    ghost = np.mean(np.abs(plain[strip] - truth[strip]))
    after = np.mean(np.abs(true[strip] - truth[strip]))
    print(f"ghosting error in image 0's hidden strip ({strip.sum()} cells): plain {ghost:.3f}, true ortho {after:.4f}")
    assert ghost > 0.3  # the plain ortho shows the roof (or wall) there
    assert after < 0.02 and ghost / after > 20
    assert np.all(info["source"][strip] == 1)  # taken from the image that sees it
    # behind the walls both cameras face side-on (y = +-20 m) ground hidden from both: nodata, +- 1 cell
    both = hidden[0] & hidden[1]
    assert both.sum() > 50
    assert not np.any(np.isnan(true) & ~footprint & ~binary_dilation(both))
    assert np.all(np.isnan(true[binary_erosion(both)]))
    # elsewhere on the ground the true ortho is the ground truth too (both images' hidden strips filled)
    ground = ~footprint & ~near & np.isfinite(true)
    assert np.mean(ground) > 0.8
    assert np.percentile(np.abs(true[ground] - truth[ground]), 99) < 0.03
    # the roof is the roof
    roof = binary_erosion(footprint, iterations=2)
    assert np.allclose(true[roof], ROOF, atol=1e-6)


def test_mark_block_and_bad_input(block):
    camera, exteriors, images, dsm, _, grid, _, _ = block
    marked = ptx.true_ortho(images, exteriors, camera, dsm, grid, occlusion="mark")
    one, _ = ptx.orthorectify(images[0], exteriors[0], camera, dsm, grid, occlusion="mark")
    np.testing.assert_array_equal(marked, one)
    with pytest.raises(ValueError, match="occlusion"):
        ptx.true_ortho(images, exteriors, camera, dsm, grid, occlusion="zbuffer")
    with pytest.raises(ValueError, match="occlusion"):
        ptx.orthorectify(images[0], exteriors[0], camera, dsm, grid, occlusion="fill")
    with pytest.raises(ValueError, match="tolerance"):
        ptx.occlusion_mask(exteriors[0], camera, dsm, grid, tolerance=-1.0)
    with pytest.raises(ValueError, match="2 images but 1"):
        ptx.true_ortho(images, exteriors[:1], [camera], dsm, grid)


@pytest.mark.filterwarnings("ignore:the camera .RPC, push-broom. needs ellipsoidal")
def test_pushbroom_mask_agrees_with_its_line_of_sight():
    """A push-broom satellite 20 deg off nadir over a 60 m box: the z-buffer with depth = -height
    against a march along the line of sight (its direction from the camera's own to_ground at two
    heights, constant over the 600 m grid: 620 km away), 4 m cells."""
    import pyproj

    from photax.scene import pushbroom_scene
    from photax.sensor import utm_crs

    scene = pushbroom_scene(roll=20.0, gsd=4.0, image_size=(300, 300), n_gcp=6, n_check=0)
    cam = scene.camera
    crs = utm_crs(10.0, 45.0)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    cx, cy = (float(v) for v in to_utm.transform(10.0, 45.0))
    cx, cy = round(cx), round(cy)
    half, cell, box, top = 500, 4.0, 80.0, 60.0
    xc = -half + cell * (np.arange(int(2 * half / cell)) + 0.5)
    heights = np.where((np.abs(xc[None]) < box) & (np.abs(xc[:, None]) < box), top, 0.0)
    dsm = ptx.DEM(heights, (cell, 0.0, cx - half, 0.0, -cell, cy + half), crs=crs)
    grid = ptx.Grid((cell, 0.0, cx - 300, 0.0, -cell, cy + 300), (150, 150), crs=crs)
    mask = ptx.occlusion_mask(None, cam, dsm, grid)
    # the line of sight at the grid's centre: ground shift per metre of height
    lon, lat = 10.0, 45.0
    pix = np.asarray(cam(np.array([[lon, lat, 0.0]])))
    ends = [np.asarray(cam.to_ground(pix, h))[0] for h in (0.0, 100.0)]
    (x0, y0), (x1, y1) = (to_utm.transform(*e) for e in ends)
    d = np.array([x1 - x0, y1 - y0]) / 100.0
    assert 0.3 < np.hypot(*d) < 0.5  # about tan(20 deg) on the ground
    gx = -300 + cell * (np.arange(150) + 0.5)
    gx, gy = np.meshgrid(gx, -gx)
    z0 = np.where((np.abs(gx) < box) & (np.abs(gy) < box), top, 0.0)
    z = z0[None] + np.linspace(0, top, 241)[1:, None, None] * (z0[None] < top)
    x, y = gx + d[0] * (z - z0), gy + d[1] * (z - z0)
    surface = map_coordinates(heights, [half / cell - y / cell - 0.5, x / cell + half / cell - 0.5], order=1)
    ref = np.any(surface > z + 1e-6, axis=0)
    agree = np.mean(mask == ref)
    print(f"push-broom: hidden {ref.sum()} cells (line of sight), z-buffer {mask.sum()}, agreement {agree:.4f}")
    assert ref.sum() > 150
    assert agree >= 0.99


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_file_ortho_marks_the_same_cells(block, tmp_path):
    import rasterio

    camera, exteriors, images, dsm, _, grid, _, _ = block
    src = tmp_path / "img.tif"
    with rasterio.open(src, "w", driver="GTiff", width=SIZE[0], height=SIZE[1], count=1, dtype="float64") as dst:
        dst.write(images[0], 1)
    ptx.orthorectify_file(src, tmp_path / "o.tif", exteriors[0], camera, dsm, grid, occlusion="mark")
    with rasterio.open(tmp_path / "o.tif") as ds:
        on_file = ds.read(1)
    in_memory, _ = ptx.orthorectify(images[0], exteriors[0], camera, dsm, grid, occlusion="mark")
    np.testing.assert_array_equal(np.isnan(on_file), np.isnan(in_memory))
    assert np.isnan(on_file).sum() > 300
    np.testing.assert_allclose(on_file, in_memory, atol=1e-6)


def test_cli_occlusion_needs_one_frame_image_and_a_dsm(tmp_path, capsys):
    from photax.cli import main

    args = ["ortho", "a.tif", "b.tif", "--camera", "c.yaml", "--exterior", "e.csv", "--dem", "d.tif"]
    assert main([*args, "--out-dir", str(tmp_path), "--occlusion", "mark"]) == 2
    assert "--occlusion mark: one frame IMAGE" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_cli_occlusion_mark(block, tmp_path):
    import rasterio

    from photax.cli import main
    from photax.io import write_camera
    from photax.io.orthority import write_orthority_exterior

    camera, exteriors, images, dsm, heights, _, _, _ = block
    crs = "EPSG:32633"
    src, dem_path = tmp_path / "img.tif", tmp_path / "dsm.tif"
    with rasterio.open(src, "w", driver="GTiff", width=SIZE[0], height=SIZE[1], count=1, dtype="float64") as dst:
        dst.write(images[0], 1)
    profile = dict(driver="GTiff", width=160, height=160, count=1, dtype="float64", crs=crs)
    with rasterio.open(dem_path, "w", transform=rasterio.Affine(*np.asarray(dsm.transform)), **profile) as dst:
        dst.write(heights, 1)
    write_camera(camera, tmp_path / "cam.yaml")
    write_orthority_exterior(tmp_path / "ext.csv", {"img.tif": exteriors[0]}, crs)
    args = ["ortho", str(src), "--camera", str(tmp_path / "cam.yaml"), "--exterior", str(tmp_path / "ext.csv")]
    args += ["--dem", str(dem_path), "--resolution", "1", "--no-progress"]
    assert main([*args, "--occlusion", "mark", "-o", str(tmp_path / "true.tif")]) == 0
    assert main([*args, "-o", str(tmp_path / "plain.tif")]) == 0
    with rasterio.open(tmp_path / "true.tif") as t, rasterio.open(tmp_path / "plain.tif") as p:
        true, plain = t.read(1), p.read(1)
        grid = ptx.Grid(t.transform, (t.height, t.width), crs=crs)
    hidden = ptx.occlusion_mask(exteriors[0], camera, ptx.read_dem(dem_path), grid)
    assert hidden.sum() > 300
    np.testing.assert_array_equal(np.isnan(true), np.isnan(plain) | hidden)
    np.testing.assert_array_equal(true[~hidden], plain[~hidden])


def test_mask_on_a_grid_finer_than_the_dsm(block):
    """0.4 m cells on the 1 m DSM (about the images' 0.375 m pixels): the surface is sampled at the
    DSM's and the buffer's resolution, not the grid's, and still agrees with ray marching."""
    camera, exteriors, _, dsm, heights, _, _, _ = block
    n = 250
    grid = ptx.Grid((100 / n, 0.0, X0 - 50, 0.0, -100 / n, Y0 + 50), (n, n))
    gx = -50 + 100 / n * (np.arange(n) + 0.5)
    gx, gy = np.meshgrid(gx, -gx)
    mask = ptx.occlusion_mask(exteriors[0], camera, dsm, grid)
    ref = _marched(exteriors[0], heights, gx, gy, steps=300)
    agree = np.mean(mask == ref)
    print(f"0.4 m grid: hidden {ref.sum()} cells (ray marching), z-buffer {mask.sum()}, agreement {agree:.4f}")
    assert ref.sum() > 2000 and agree >= 0.99
