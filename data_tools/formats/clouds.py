"""Point-cloud files for map classification: LAS/LAZ (streamed in chunks with laspy; LAZ through
the ``lazrs`` backend), PCD and PLY (:mod:`data_tools.formats.pcd`), NPY (an ``(N, 3)`` array,
memory-mapped; ``(N, k > 3)``: x, y, z are the first three columns; a structured array: its
``x``, ``y``, ``z`` fields), NPZ (such an array, alone or named ``points`` / ``xyz``; an Ouster
sweep ``.npz`` is a sequence, not a cloud).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.laz import laz_backend, open_las  # noqa: F401 (laz_backend: importable from here too)

CLOUD_SUFFIXES = (".las", ".laz", ".ply", ".pcd", ".npy")
#: a horizontal extent below this (in the file's units) with a vertical one 100 times larger,
#: within +-180 / +-90: geographic degrees, not metres
DEGREE_EXTENT = 0.05
#: LAS scales (m) coarser than this lose the structure map classification looks at
COARSE_SCALE = 0.05

log = logging.getLogger("prc_slam.readers")
_warned_coarse: set[str] = set()


def check_metric(path: Path, lo: np.ndarray, hi: np.ndarray) -> None:
    """Raise :class:`DataError` when the bounding box ``lo``..``hi`` (x, y, z) looks like
    longitude / latitude in degrees with heights in metres (a geographic CRS): every step
    after would take 1e-5 degrees for 1e-5 metres."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return
    ext = hi - lo
    horiz = float(max(ext[0], ext[1]))
    in_degrees = abs(lo[0]) <= 180 and abs(hi[0]) <= 180 and abs(lo[1]) <= 90 and abs(hi[1]) <= 90
    if in_degrees and horiz < DEGREE_EXTENT and float(ext[2]) > 100 * max(horiz, 1e-12):
        raise DataError(
            f"{path}: x/y look like geographic degrees (x {lo[0]:.6f}..{hi[0]:.6f}, y {lo[1]:.6f}..{hi[1]:.6f}, "
            f"z spans {ext[2]:.1f}): reproject the cloud to a metric CRS (e.g. UTM) first"
        )


def warn_coarse_storage(path: Path, dtype: np.dtype, lo: np.ndarray, hi: np.ndarray) -> None:
    """Warn once per file when floating-point coordinates of this ``dtype`` (float32: 24 bits) are
    stored with a step coarser than :data:`COARSE_SCALE` at the cloud's largest coordinate:
    geo-referenced clouds (UTM northing ~5e6 m) written as float32 keep one value per 0.5 m."""
    dtype = np.dtype(dtype)
    if dtype.kind != "f" or dtype.itemsize >= 8:
        return
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return
    largest = float(np.max(np.abs(np.concatenate([lo, hi]))))
    step = float(np.spacing(dtype.type(largest)))
    if step > COARSE_SCALE and str(path) not in _warned_coarse:
        _warned_coarse.add(str(path))
        log.warning(
            "%s: %s coordinates as large as %.6g are stored with a step of %g: structure finer than that is lost "
            "(store them as float64, or relative to an offset)",
            path,
            dtype.name,
            largest,
            step,
        )


#: arrays an ``.npz`` cloud may name its points by (one array alone needs no name)
NPZ_POINT_KEYS = ("points", "xyz", "positions")


def _is_ouster_npz(path: Path) -> bool:
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            return "range_mm.npy" in zf.namelist()
    except (zipfile.BadZipFile, OSError):
        return False


def is_cloud_file(path: str | Path) -> bool:
    """A file map classification reads as one cloud (an Ouster ``.npz`` is a sweep to accumulate)."""
    path = Path(path)
    if not path.is_file():
        return False
    suffix = path.suffix.lower()
    return suffix in CLOUD_SUFFIXES or (suffix == ".npz" and not _is_ouster_npz(path))


def _check(path: Path, xyz: np.ndarray) -> np.ndarray:
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DataError(f"{path}: expected (N, 3) coordinates, got shape {xyz.shape}")
    return xyz


def _array_xyz(path: Path, arr: np.ndarray) -> np.ndarray:
    """x, y, z of a NumPy point array: ``(N, 3)``; ``(N, k > 3)`` (x, y, z first, then e.g.
    intensity or normals); a structured array with ``x``, ``y``, ``z`` fields. Anything else
    (``(3, N)``, one column, strings) is a one-line error."""
    if arr.dtype.names is not None:
        missing = [a for a in "xyz" if a not in arr.dtype.names]
        if missing or arr.ndim != 1:
            raise DataError(
                f"{path}: a structured array needs 1-D x, y, z fields; it has fields {list(arr.dtype.names)} "
                f"and shape {arr.shape}"
            )
        return np.column_stack([np.asarray(arr[a], np.float64) for a in "xyz"])
    if arr.dtype.kind not in "fiu":
        raise DataError(f"{path}: expected numeric point coordinates, got dtype {arr.dtype}")
    if arr.ndim == 2 and arr.shape[1] > 3 and arr.shape[0] > 3:
        log.info("%s: %d columns per point: x, y, z taken from the first three", path, arr.shape[1])
        return arr[:, :3]
    if arr.ndim == 2 and arr.shape[0] == 3 and arr.shape[1] > 3:
        raise DataError(f"{path}: shape {arr.shape} looks like x, y, z rows: save the transpose, (N, 3)")
    return _check(path, arr)


def _npz_points(path: Path) -> np.ndarray:
    """The point array of a non-Ouster ``.npz``: its only array, or the one named as in
    :data:`NPZ_POINT_KEYS`."""
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = list(z.files)
            key = keys[0] if len(keys) == 1 else next((k for k in NPZ_POINT_KEYS if k in keys), None)
            if key is None:
                raise DataError(
                    f"{path}: which array holds the points? It has {keys}; name it one of {', '.join(NPZ_POINT_KEYS)}"
                )
            return z[key]
    except DataError:
        raise
    except (ValueError, OSError) as e:
        raise DataError(f"{path}: not a readable .npz archive ({e})") from e


def check_record_count(path: Path, header) -> None:
    """Raise :class:`DataError` when an uncompressed LAS file holds whole point records beyond the
    count its header announces (up to its EVLRs or its end): laspy reads the announced count
    only, and the points after it were lost without a word; or fewer (a cut file: laspy's
    'buffer size must be a multiple of element size' did not say so)."""
    if header.are_points_compressed:
        return
    size = path.stat().st_size
    record = int(header.point_format.size)
    end = int(header.offset_to_point_data) + int(header.point_count) * record
    if end > size:
        held = max(size - int(header.offset_to_point_data), 0) // record if record else 0
        raise DataError(f"{path}: header announces {int(header.point_count)} points, file holds {held} (truncated?)")
    limit = int(getattr(header, "start_of_first_evlr", 0) or 0)
    limit = limit if end <= limit <= size else size
    extra = (limit - end) // record if record else 0
    if extra >= 1:
        raise DataError(
            f"{path}: header announces {int(header.point_count)} points, the file holds {extra} more point records "
            "after them (a header count not updated by the writer?)"
        )


def cloud_size(path: str | Path) -> int:
    """Number of points in a cloud file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".las", ".laz"):
        with open_las(path) as f:
            check_record_count(path, f.header)
            return int(f.header.point_count)
    return sum(len(c) for c in cloud_chunks(path))


def cloud_chunks(path: str | Path, chunk: int = 2_000_000) -> Iterator[np.ndarray]:
    """The cloud's coordinates as ``float64 (n, 3)`` chunks, in file order.

    LAS/LAZ and NPY files are read chunk by chunk (NPY memory-mapped); PCD and PLY (our readers)
    are read whole and then cut.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in (*CLOUD_SUFFIXES, ".npz"):
        raise DataError(f"{path}: unknown cloud format {suffix!r}; use one of {', '.join(CLOUD_SUFFIXES)}, .npz")
    if suffix in (".las", ".laz"):
        with open_las(path) as f:
            expected = int(f.header.point_count)
            check_record_count(path, f.header)
            if expected:
                check_metric(path, f.header.mins, f.header.maxs)
                scale = float(np.max(f.header.scales))
                if scale > COARSE_SCALE and str(path) not in _warned_coarse:
                    _warned_coarse.add(str(path))  # once per file (the cloud may be read twice)
                    log.warning(
                        "%s: coordinates are quantised to %g (the LAS scale): structure finer than that is lost",
                        path,
                        scale,
                    )
            seen = 0
            for pts in f.chunk_iterator(chunk):
                seen += len(pts)
                yield np.column_stack([np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)])
        if seen != expected:
            raise DataError(f"{path}: header announces {expected} points, file holds {seen} (truncated?)")
        return
    if suffix in (".npy", ".npz"):
        try:
            arr = _npz_points(path) if suffix == ".npz" else np.load(path, mmap_mode="r", allow_pickle=False)
        except DataError:
            raise
        except ValueError as e:
            raise DataError(f"{path}: not a readable .npy array ({e})") from e
        xyz = _array_xyz(path, arr)
        stored = max((arr.dtype[a] for a in "xyz"), key=lambda d: d.itemsize) if arr.dtype.names else xyz.dtype
    elif suffix == ".pcd":  # our reader: any field type and layout, one-line errors
        from data_tools.formats.pcd import read_sweep_fields

        fields = read_sweep_fields(path)[0]
        stored = max((fields[a].dtype for a in "xyz"), key=lambda d: d.itemsize)
        xyz = np.column_stack([fields["x"], fields["y"], fields["z"]])
    else:  # PLY: our reader (ascii or binary, either endianness; truncation and missing x/y/z said)
        from data_tools.formats.pcd import read_ply

        fields = read_ply(path)
        missing = [a for a in "xyz" if a not in fields]
        if missing:
            raise DataError(f"{path}: the PLY vertices have no {', '.join(missing)} (properties {list(fields)})")
        stored = max((fields[a].dtype for a in "xyz"), key=lambda d: d.itemsize)
        xyz = np.column_stack([np.asarray(fields[a], np.float64) for a in "xyz"])
    if len(xyz):
        finite = np.isfinite(xyz).all(axis=1)
        if finite.any():
            lo, hi = np.min(xyz[finite], axis=0), np.max(xyz[finite], axis=0)
            check_metric(path, lo, hi)
            warn_coarse_storage(path, stored, lo, hi)
    for i in range(0, len(xyz), chunk):
        yield np.asarray(xyz[i : i + chunk], dtype=np.float64)


#: VLRs that tell a LAS file's coordinate reference system (copied to the classified clouds)
CRS_VLRS = ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr", "GeoDoubleParamsVlr", "GeoAsciiParamsVlr")


def cloud_crs(path: str | Path) -> list:
    """A LAS/LAZ file's coordinate reference system records (WKT and GeoTIFF-key VLRs), to write
    beside the classified points (a UTM tile's outputs lost their CRS: a GIS placed them nowhere);
    empty for other formats and for files without them."""
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        return []
    with open_las(path) as f:
        vlrs = list(f.header.vlrs)
    return [v for v in vlrs if type(v).__name__ in CRS_VLRS]


def cloud_grid(path: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """A LAS/LAZ file's ``(scales, offsets)``, for the classified clouds to store the points on
    the input's own grid (a 0.1 mm input written at 1 mm moved its points by up to 0.5 mm);
    None for other formats."""
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        return None
    with open_las(path) as f:
        return np.array(f.header.scales, np.float64), np.array(f.header.offsets, np.float64)


def cloud_classes(path: str | Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None] | None:
    """A LAS/LAZ file's own classes (``classification``, and the ``instance`` dimension when
    present), to score a map against, and the points to score (None: all; LAS withheld points,
    which the specification says to treat as deleted, are not scored); None for other formats
    and for files whose classes are only 0 (never classified) and 1 (unclassified)."""
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        return None
    with open_las(path) as f:  # chunk by chunk, the three dimensions only (laspy.read held every dimension)
        check_record_count(path, f.header)
        n = int(f.header.point_count)
        names = set(f.header.point_format.dimension_names)
        codes = np.zeros(n, np.uint8)
        inst = np.zeros(n, np.uint32) if "instance" in names else None
        withheld = np.zeros(n, bool) if "withheld" in names else None
        start = 0
        for pts in f.chunk_iterator(2_000_000):
            stop = start + len(pts)
            if stop > n:
                raise DataError(f"{path}: header announces {n} points, the file holds more")
            codes[start:stop] = np.asarray(pts.classification)
            if inst is not None:
                inst[start:stop] = np.asarray(pts["instance"])
            if withheld is not None:
                withheld[start:stop] = np.asarray(pts.withheld, bool)
            start = stop
    if start != n:
        raise DataError(f"{path}: header announces {n} points, file holds {start} (truncated?)")
    if not np.isin(codes, (0, 1), invert=True).any():
        return None
    scored = None if withheld is None or not withheld.any() else ~withheld
    return codes, inst, scored
