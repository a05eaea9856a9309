"""A triangulated point cloud (:class:`PointCloud`) and its PLY and LAS / LAZ writers and readers."""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np


@dataclasses.dataclass(frozen=True)
class PointCloud:
    """Points triangulated from a stereo pair.

    Attributes:
        xyz: ``(n, 3)`` float64 ground ``(X, Y, Z)`` in ``crs`` (a ground camera's ``Z`` is the
            ellipsoidal height, m).
        residual: ``(n,)`` the intersection residual: RMS of the point's reprojection errors in the
            two images (px).
        sigma_z: ``(n,)`` the height's standard deviation from a disparity standard deviation
            (``|dZ/dd| sigma_d``, m).
        colour: ``(n, 3)`` uint8 RGB (the left image's grey values), or None.
        crs: the CRS of ``xyz`` (anything rasterio accepts), or None.
    """

    xyz: np.ndarray
    residual: np.ndarray
    sigma_z: np.ndarray
    colour: np.ndarray | None = None
    crs: object = None

    def __post_init__(self):
        xyz = np.asarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        n = len(xyz)
        for name in ("residual", "sigma_z"):
            v = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if len(v) != n:
                raise ValueError(f"{name} has {len(v)} values for {n} points")
            object.__setattr__(self, name, v)
        if self.colour is not None:
            c = np.asarray(self.colour)
            if c.shape != (n, 3):
                raise ValueError(f"colour must have shape ({n}, 3), got {c.shape}")
            object.__setattr__(self, "colour", c.astype(np.uint8))
        object.__setattr__(self, "xyz", xyz)

    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def x(self) -> np.ndarray:
        return self.xyz[:, 0]

    @property
    def y(self) -> np.ndarray:
        return self.xyz[:, 1]

    @property
    def z(self) -> np.ndarray:
        return self.xyz[:, 2]

    @classmethod
    def concatenate(cls, clouds) -> PointCloud:
        """One cloud of several (of one CRS; colours kept when every cloud has them)."""
        clouds = list(clouds)
        if not clouds:
            raise ValueError("no point clouds to concatenate")
        colour = None if any(c.colour is None for c in clouds) else np.concatenate([c.colour for c in clouds])
        return cls(
            np.concatenate([c.xyz for c in clouds]),
            np.concatenate([c.residual for c in clouds]),
            np.concatenate([c.sigma_z for c in clouds]),
            colour,
            clouds[0].crs,
        )

    def select(self, keep) -> PointCloud:
        """The points where the boolean ``keep`` ``(n,)`` is True."""
        keep = np.asarray(keep, dtype=bool)
        colour = None if self.colour is None else self.colour[keep]
        return PointCloud(self.xyz[keep], self.residual[keep], self.sigma_z[keep], colour, self.crs)

    def write_ply(self, path) -> pathlib.Path:
        """Write a binary little-endian PLY: ``double x y z``, ``uchar red green blue`` (if coloured),
        ``float residual sigma_z``; atomically (a temporary file renamed)."""
        from ..io.atomic import atomic_write

        path = pathlib.Path(path)
        fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
        if self.colour is not None:
            fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        fields += [("residual", "<f4"), ("sigma_z", "<f4")]
        rec = np.empty(len(self), dtype=fields)
        rec["x"], rec["y"], rec["z"] = self.xyz.T
        if self.colour is not None:
            rec["red"], rec["green"], rec["blue"] = self.colour.T
        rec["residual"], rec["sigma_z"] = self.residual, self.sigma_z
        names = {"<f8": "double", "u1": "uchar", "<f4": "float"}
        header = ["ply", "format binary_little_endian 1.0", "comment photax stereo point cloud"]
        if self.crs is not None:
            header.append(f"comment crs {_crs_line(self.crs)}")
        header.append(f"element vertex {len(self)}")
        header += [f"property {names[t]} {n}" for n, t in fields]
        header.append("end_header")
        data = ("\n".join(header) + "\n").encode("ascii") + rec.tobytes()
        with atomic_write(path, "wb") as f:
            f.write(data)
        return path

    def write_las(self, path, *, inputs=()) -> pathlib.Path:
        """Write a LAS 1.4 file (``.laz``: LAZ, compressed), georeferenced, atomically; needs laspy (the
        ``las`` extra: ``pip install "photax[las]"``).

        Points are stored as 32-bit integers, scale 1 mm (1e-8 degree in a geographic CRS; 1 mm for z),
        offset the cloud's minimum rounded down to a whole unit: each coordinate within half a millimetre.
        The CRS goes in an OGC WKT VLR (WKT1, WKT2 where WKT1 cannot express it), the colour as 16-bit
        RGB (``c * 257``), ``residual`` and ``sigma_z`` as float32 extra bytes dimensions of those names
        (the layout: docs/formats.md, *Point clouds*).  What ODM, PDAL, CloudCompare, QGIS and lidR read.

        Args:
            path: the output; ``.laz`` compressed (lazrs), any other suffix uncompressed LAS.
            inputs: paths ``path`` may not be (the run's inputs).

        Raises:
            ValueError: a cloud with no points, a point not finite, or one spanning more than 32-bit
                integers hold at 1 mm (2147 km).
            CRSMismatchError: a CRS pyproj cannot read.
            ModuleNotFoundError: laspy (or for ``.laz`` lazrs) missing; the message names the extra.

        Examples:
            Written and read back: coordinates within half a millimetre, the CRS, colour and extras kept:

            >>> import pathlib, tempfile
            >>> import numpy as np
            >>> from photax.stereo import PointCloud, read_las
            >>> xyz = np.array([[500000.1234, 4000000.5678, 101.25], [500010.0, 4000020.0, 99.0]])
            >>> cloud = PointCloud(xyz, [0.2, 0.4], [0.05, 0.1], [[10, 20, 30], [255, 0, 128]], "EPSG:32633")
            >>> out = cloud.write_las(pathlib.Path(tempfile.mkdtemp()) / "points.laz")
            >>> back = read_las(out)
            >>> bool(np.abs(back.xyz - xyz).max() <= 0.0005), back.crs, back.colour[1].tolist()
            (True, 'EPSG:32633', [255, 0, 128])
            >>> np.allclose(back.sigma_z, cloud.sigma_z)
            True
        """
        from ._las import write_las

        return write_las(path, self.xyz, self.residual, self.sigma_z, self.colour, self.crs, inputs)


def _crs_line(crs) -> str:
    from rasterio.crs import CRS

    c = CRS.from_user_input(crs)
    epsg = c.to_epsg()
    return f"EPSG:{epsg}" if epsg else c.to_wkt().replace("\n", " ")


def read_ply(path) -> dict:
    """The vertex properties of a binary little-endian PLY as arrays (what :meth:`PointCloud.write_ply`
    writes), for checks."""
    raw = pathlib.Path(path).read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    if lines[:2] != ["ply", "format binary_little_endian 1.0"]:
        raise ValueError(f"{path}: not a binary little-endian PLY")
    types = {"double": "<f8", "float": "<f4", "uchar": "u1"}
    n = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    fields = [(ln.split()[2], types[ln.split()[1]]) for ln in lines if ln.startswith("property")]
    rec = np.frombuffer(raw[end:], dtype=fields, count=n)
    return {name: rec[name].copy() for name, _ in fields}


def read_las(path) -> PointCloud:
    """A LAS / LAZ file as a :class:`PointCloud` (what :meth:`PointCloud.write_las` writes, or any
    writer's: ``residual`` / ``sigma_z`` NaN where the file has no such extra bytes dimension, colour
    ``RGB >> 8`` or None, the CRS from its WKT or GeoTIFF VLR: ``"EPSG:n"`` where the code says it all,
    else WKT; None without one).  Needs laspy (the ``las`` extra).

    Raises:
        UnreadableFileError: no such file.
        MalformedFileError: not a LAS / LAZ file, or its CRS cannot be read.

    Examples:
        A cloud without colour nor CRS, through an uncompressed LAS:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.stereo import PointCloud, read_las
        >>> cloud = PointCloud([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], [0.1, 0.2], [0.3, 0.4])
        >>> back = read_las(cloud.write_las(pathlib.Path(tempfile.mkdtemp()) / "p.las"))
        >>> back.xyz.tolist(), back.colour, back.crs
        ([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], None, None)
    """
    from ._las import read_las as _read

    d = _read(path)
    return PointCloud(d["xyz"], d["residual"], d["sigma_z"], d["colour"], d["crs"])
