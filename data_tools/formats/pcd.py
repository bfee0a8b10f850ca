"""Folders of sweeps (``.pcd`` / ``.ply`` / ``.bin``) and single sweep files (also ``.las`` / ``.laz``),
organised into Scans by the one organiser (:class:`data_tools.organize.Organizer`).

- Files are taken sorted by name; the frame name is the file stem (so per-frame outputs keep it).
- Frame times come from a ``times.txt`` beside the sweeps (one line per sweep) when present,
  else from the earliest per-point time, else they are unknown.
- Sweeps may differ in size: each is organised on its own, with the beam table found on the
  first sweep reused for the next (one :class:`Organizer` per folder).
- A ``ring`` / ``channel`` / ``laser_id`` (...) field is passed to the organiser as the ring;
  a ``t`` / ``time`` / ``timestamp`` / ``offset_time`` (...) field as per-point times, converted to
  seconds (see :func:`times_in_seconds`). An organised PCD (``HEIGHT`` > 1, the Ouster ROS
  driver's layout) keeps its grid (:meth:`Organizer.scan_organized`).

The PCD reader handles ``ascii``, ``binary`` and ``binary_compressed`` (LZF) data, fields of
type ``F`` (2, 4, 8 bytes), ``I`` and ``U`` (1, 2, 4, 8 bytes) with any ``COUNT``; anything else
is a one-line :class:`DataError` naming the file. :func:`write_pcd` writes binary PCDs (the
``filter`` command's PCD folder output: the input fields plus ``label``).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import lzf
import numpy as np

from data_tools.errors import DataError
from data_tools.sequence import ORGANISER_OPTIONS, Reader, SequenceBase, organiser_hints
from data_tools.units import warn_unless_metres
from prc_slam.scan import Scan

log = logging.getLogger("prc_slam.readers")

SWEEP_SUFFIXES = (".pcd", ".ply", ".bin")
SINGLE_SUFFIXES = (*SWEEP_SUFFIXES, ".las", ".laz")
#: field names taken as the ring / beam index, in order of preference (not Livox's ``line``: the
#: laser of a non-repetitive pattern, whose points of one laser do not form a scan line)
RING_FIELDS = ("ring", "channel", "laser_id", "laser_number", "laser", "beam")
#: field names taken as per-point times, in order of preference
TIME_FIELDS = ("t", "time", "timestamp", "offset_time", "time_stamp", "time_offset", "gps_time")
INTENSITY_FIELDS = ("intensity", "reflectivity", "remission", "signal")

_PCD_TYPES = {("F", 2): "<f2", ("F", 4): "<f4", ("F", 8): "<f8"}
_PCD_TYPES.update({("I", s): f"<i{s}" for s in (1, 2, 4, 8)})
_PCD_TYPES.update({("U", s): f"<u{s}" for s in (1, 2, 4, 8)})
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


# ------------------------------------------------------------------------------------ PCD


def _parse_pcd_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise DataError(f"{path}: not a PCD file (header has no DATA line)")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            return header, pos
        if len(header) > 32:
            raise DataError(f"{path}: not a PCD file (no DATA line in the header)")


def read_pcd(path: str | Path) -> tuple[dict[str, np.ndarray], tuple[int, int]]:
    """Read a PCD file.

    Returns
    -------
    fields : dict name -> array (N,) or (N, COUNT), in the file's types and point order
    (height, width) : the organisation (height 1 for an unorganised cloud)
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    if raw.lstrip()[:1] not in (b"#", b"V", b"F"):
        raise DataError(f"{path}: not a PCD file")
    header, start = _parse_pcd_header(path, raw)
    for key in ("FIELDS", "SIZE", "TYPE", "DATA"):
        if key not in header:
            raise DataError(f"{path}: PCD header has no {key} line")
    names = header["FIELDS"]
    n_f = len(names)
    counts = header.get("COUNT", ["1"] * n_f)
    if not (len(header["SIZE"]) == len(header["TYPE"]) == len(counts) == n_f):
        raise DataError(f"{path}: PCD header: FIELDS, SIZE, TYPE and COUNT have different lengths")
    try:
        sizes = [int(s) for s in header["SIZE"]]
        counts_i = [int(c) for c in counts]
        width = int(header.get("WIDTH", ["0"])[0])
        height = int(header.get("HEIGHT", ["1"])[0])
        n = int(header.get("POINTS", [str(width * height)])[0])
    except ValueError as exc:
        raise DataError(f"{path}: PCD header has a non-integer SIZE/COUNT/WIDTH/HEIGHT/POINTS ({exc})") from exc
    dtypes = []
    for name, typ, size, count in zip(names, header["TYPE"], sizes, counts_i, strict=True):
        code = _PCD_TYPES.get((typ.upper(), size))
        if code is None:
            raise DataError(
                f"{path}: field {name!r} has an unknown PCD type {typ!r} of size {size} (known: F 2/4/8, I/U 1/2/4/8)"
            )
        if count < 1:
            raise DataError(f"{path}: field {name!r} has COUNT {count}")
        dtypes.append((name, code, count))
    # padding fields ("_") are kept as unique names so the record layout stays right
    seen: dict[str, int] = {}
    layout = []
    for name, code, count in dtypes:
        key = name if name not in seen else f"{name}#{seen[name]}"
        seen[name] = seen.get(name, 0) + 1
        layout.append((key, code, (count,)) if count > 1 else (key, code))
    rec = np.dtype(layout)
    kind = header["DATA"][0].lower() if header["DATA"] else ""
    body = raw[start:]
    if kind == "ascii":
        data = _pcd_ascii(path, body, rec, n)
    elif kind == "binary":
        if len(body) < n * rec.itemsize:
            raise DataError(f"{path}: truncated: {n} points need {n * rec.itemsize} bytes, file holds {len(body)}")
        data = np.frombuffer(body, dtype=rec, count=n)
    elif kind == "binary_compressed":
        data = _pcd_compressed(path, body, rec, n)
    else:
        raise DataError(f"{path}: unknown PCD DATA kind {kind!r} (ascii, binary or binary_compressed)")
    fields = {name: np.array(data[name]) for name in rec.names if not name.startswith("_")}
    if height < 1 or width * height != n:
        height, width = 1, n
    return fields, (height, width)


def _pcd_ascii(path: Path, body: bytes, rec: np.dtype, n: int) -> np.ndarray:
    per_point = sum(int(np.prod(rec[k].shape)) if rec[k].shape else 1 for k in rec.names)
    tokens = body.split()
    if len(tokens) < n * per_point:
        raise DataError(
            f"{path}: truncated: {n} points of {per_point} values need {n * per_point}, file holds {len(tokens)}"
        )
    table = np.array(tokens[: n * per_point]).reshape(n, per_point)
    out = np.zeros(n, dtype=rec)
    col = 0
    for name in rec.names:
        width = int(np.prod(rec[name].shape)) if rec[name].shape else 1
        base = rec[name].base if rec[name].shape else rec[name]
        try:
            vals = table[:, col : col + width].astype(np.float64 if base.kind == "f" else np.int64)
        except ValueError as exc:
            raise DataError(f"{path}: field {name!r}: not a number ({exc})") from exc
        out[name] = vals.reshape(out[name].shape)
        col += width
    return out


def _pcd_compressed(path: Path, body: bytes, rec: np.dtype, n: int) -> np.ndarray:
    if len(body) < 8:
        raise DataError(f"{path}: truncated binary_compressed data")
    csize, usize = np.frombuffer(body[:8], "<u4")
    if usize != n * rec.itemsize:
        raise DataError(f"{path}: binary_compressed holds {usize} bytes, {n} points need {n * rec.itemsize}")
    if len(body) < 8 + csize:
        raise DataError(f"{path}: truncated: compressed data of {csize} bytes, file holds {len(body) - 8}")
    packed = body[8 : 8 + int(csize)]
    try:  # liblzf (python-neo-lzf, as pypcd4): None when the data would overflow ``usize``
        buf = lzf.decompress(packed, int(usize)) if packed else b""
    except ValueError:
        buf = None
    got = -1 if buf is None else len(buf)
    if got != usize:
        raise DataError(f"{path}: corrupt binary_compressed data (LZF decoded {got} of {usize} bytes)")
    # structure of arrays: each field's values for all points, one field after the other
    out = np.empty(n, dtype=rec)
    off = 0
    for name in rec.names:
        sub = rec[name]
        out[name] = np.frombuffer(buf, dtype=sub, count=n, offset=off).reshape(out[name].shape)
        off += n * sub.itemsize
    return out


def _pcd_type(arr: np.ndarray) -> tuple[str, int]:
    dt = arr.dtype
    if dt == np.bool_:
        return "U", 1
    if dt.kind in "fiu":
        return {"f": "F", "i": "I", "u": "U"}[dt.kind], dt.itemsize
    raise DataError(f"PCD cannot store a field of dtype {dt}")


def write_pcd(path: str | Path, fields: dict[str, np.ndarray], *, height: int = 1) -> Path:
    """Write a binary PCD (v0.7) with the given fields, in order, one record per point.

    Parameters
    ----------
    fields : name -> array (N,) or (N, count) of a float, int, uint or bool dtype; ``x y z``
        first by convention (e.g. the input's fields plus ``label``)
    height : >1 for an organised cloud (N = height x width)
    """
    path = Path(path)
    if not fields:
        raise DataError(f"{path}: no fields to write")
    arrays = {k: np.asarray(v) for k, v in fields.items()}
    n = len(next(iter(arrays.values())))
    for k, v in arrays.items():
        if v.ndim not in (1, 2) or len(v) != n:
            raise DataError(f"{path}: field {k!r} has shape {v.shape}, expected ({n},) or ({n}, count)")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", k):
            raise DataError(f"{path}: field name {k!r} cannot be written to a PCD header")
    if height < 1 or n % height:
        raise DataError(f"{path}: {n} points do not fill {height} rows")
    layout, sizes, types, counts = [], [], [], []
    for k, v in arrays.items():
        t, s = _pcd_type(v)
        c = 1 if v.ndim == 1 else v.shape[1]
        code = "<" + {"F": "f", "I": "i", "U": "u"}[t] + str(s)
        layout.append((k, code, (c,)) if c > 1 else (k, code))
        sizes.append(str(s))
        types.append(t)
        counts.append(str(c))
    rec = np.zeros(n, dtype=np.dtype(layout))
    for k, v in arrays.items():
        rec[k] = v
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(arrays)}\nSIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\nCOUNT {' '.join(counts)}\n"
        f"WIDTH {n // height}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())
    return path


# ------------------------------------------------------------------------------------ PLY, bin, LAS


def read_ply(path: str | Path) -> dict[str, np.ndarray]:
    """The ``vertex`` element of a PLY file (ascii or binary, either endianness) as fields."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    if not raw.startswith(b"ply"):
        raise DataError(f"{path}: not a PLY file")
    end = raw.find(b"end_header")
    if end < 0:
        raise DataError(f"{path}: PLY header has no end_header")
    start = raw.index(b"\n", end) + 1
    fmt, n, props, element, before = None, None, [], None, 0
    for line in raw[:end].decode("ascii", errors="replace").splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            element = parts[1]
            if element == "vertex":
                n = int(parts[2])
            elif n is None:
                before += 1
        elif parts[0] == "property" and element == "vertex":
            if parts[1] == "list":
                raise DataError(f"{path}: vertex property {parts[-1]!r} is a list (not supported)")
            code = _PLY_TYPES.get(parts[1])
            if code is None:
                raise DataError(f"{path}: vertex property {parts[-1]!r} has an unknown PLY type {parts[1]!r}")
            props.append((parts[2], code))
    if n is None or not props:
        raise DataError(f"{path}: PLY file has no vertex element")
    if before:
        raise DataError(f"{path}: PLY elements before 'vertex' are not supported")
    if fmt == "ascii":
        data = _pcd_ascii(path, raw[start:], np.dtype(props), n)
        return {k: data[k] for k in data.dtype.names}
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise DataError(f"{path}: unknown PLY format {fmt!r}")
    endian = "<" if fmt == "binary_little_endian" else ">"
    rec = np.dtype([(k, endian + c) for k, c in props])
    if len(raw) - start < n * rec.itemsize:
        raise DataError(f"{path}: truncated: {n} vertices need {n * rec.itemsize} bytes, file holds {len(raw) - start}")
    data = np.frombuffer(raw, dtype=rec, count=n, offset=start)
    return {k: data[k].astype(data[k].dtype.newbyteorder("=")) for k in rec.names}


def read_bin(path: str | Path) -> dict[str, np.ndarray]:
    """A KITTI-layout ``.bin``: float32 ``x y z intensity`` per point; nuScenes' ``x y z intensity
    ring`` (:func:`looks_like_ring_bin`) adds a ``ring`` field."""
    path = Path(path)
    try:
        raw = np.fromfile(path, dtype="<f4")
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    if raw.size and looks_like_ring_bin(raw):
        pts = raw.reshape(-1, 5)
        return {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "intensity": pts[:, 3], "ring": pts[:, 4]}
    if raw.size % 4:
        raise DataError(f"{path}: truncated: {path.stat().st_size} bytes is not a whole number of 16-byte points")
    pts = raw.reshape(-1, 4)
    return {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "intensity": pts[:, 3]}


def looks_like_ring_bin(raw: np.ndarray) -> bool:
    """Whether a flat float32 ``.bin`` holds nuScenes' five values per point (x y z intensity
    ring, ``*.pcd.bin``) rather than KITTI's four: a whole number of 20-byte points whose fifth
    value is a small whole number (a beam index) for every point. Read as five values, KITTI's
    four-value points put x, y, z and intensity in turn in that place: never all whole."""
    if raw.size % 5:
        return False
    ring = raw[4::5]
    with np.errstate(invalid="ignore"):
        return bool(np.all((ring >= 0) & (ring < 1024) & (ring == np.floor(ring))))


def read_las_fields(path: str | Path) -> dict[str, np.ndarray]:
    """A ``.las`` / ``.laz`` cloud's coordinates and point dimensions as fields (LAZ via lazrs)."""
    import laspy

    from data_tools.formats.laz import laz_backend

    path = Path(path)
    backend = laz_backend(path)
    try:
        las = laspy.read(path, laz_backend=backend)
    except (laspy.LaspyException, ValueError, OSError, RuntimeError) as exc:
        raise DataError(f"{path}: not a readable LAS file ({' '.join(str(exc).split())})") from exc
    fields = {
        "x": np.asarray(las.x, np.float64),
        "y": np.asarray(las.y, np.float64),
        "z": np.asarray(las.z, np.float64),
    }
    for name in las.point_format.dimension_names:
        if name in ("X", "Y", "Z"):
            continue
        arr = np.asarray(las[name])
        if arr.ndim == 1 and arr.dtype.kind in "fiub":
            fields[name] = arr
    return fields


def read_sweep_fields(path: str | Path) -> tuple[dict[str, np.ndarray], tuple[int, int]]:
    """Fields of one sweep file and its organisation ``(height, width)`` (height 1: unorganised)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".pcd":
        fields, hw = read_pcd(path)
    else:
        if suffix == ".ply":
            fields = read_ply(path)
        elif suffix == ".bin":
            fields = read_bin(path)
        elif suffix in (".las", ".laz"):
            fields = read_las_fields(path)
        else:
            raise DataError(f"{path}: unknown sweep format {suffix!r} (use {', '.join(SINGLE_SUFFIXES)})")
        hw = (1, len(next(iter(fields.values()))) if fields else 0)
    for axis in "xyz":
        if axis not in fields:
            raise DataError(f"{path}: the cloud has no {axis!r} field (fields: {', '.join(fields) or 'none'})")
    return fields, hw


# ------------------------------------------------------------------------------------ times


def times_in_seconds(values: np.ndarray, name: str, source: str) -> tuple[np.ndarray, float]:
    """Per-point times in seconds, and the scale used.

    Drivers store times in s (Velodyne ``time``, Hesai ``timestamp``), ns (Ouster ``t``, Livox
    ``offset_time``, Autoware ``time_stamp``) or us. The unit is taken as the largest of s, ms,
    us, ns in which the sweep lasts less than one second (a sweep of a spinning sensor lasts
    10-200 ms); a sweep whose times span nothing (all equal) keeps seconds.
    """
    t = np.asarray(values, dtype=np.float64)
    if t.ndim != 1:
        raise DataError(f"{source}: time field {name!r} has {t.ndim} dimensions")
    finite = t[np.isfinite(t)]
    if len(finite) == 0:
        raise DataError(f"{source}: time field {name!r} holds no finite value")
    span = float(finite.max() - finite.min())
    for scale in (1.0, 1e-3, 1e-6, 1e-9):
        if span * scale < 1.0:
            break
    else:
        raise DataError(f"{source}: time field {name!r} spans {span:g} units: not one sweep in s, ms, us or ns")
    if scale != 1.0 and np.asarray(values).dtype.kind == "f":  # drivers' float times are seconds
        log.warning(
            "%s: float time field %r spans %g: read in units of %g s (a sweep lasts < 1 s)", source, name, span, scale
        )
    return t * scale, scale


def _line_extent(lines: np.ndarray) -> float:
    """Median over the lines of ``lines`` (L, M, 3) (NaN or zeros: no return) of the angle a
    line covers: the larger of its net azimuth travel (signed steps summed, so that the
    azimuth offsets of staggered beams cancel) and its elevation range (5-95 %); NaN when no
    line has 8 returns."""
    x, y, z = lines[..., 0], lines[..., 1], lines[..., 2]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(lines).all(axis=2) & ((x != 0) | (y != 0) | (z != 0))
    az = np.arctan2(y, x)
    el = np.arctan2(z, np.hypot(x, y))
    extents = []
    for k in range(len(lines)):  # a few dozen sampled lines
        v = ok[k]
        if v.sum() < 8:
            continue
        a, e = az[k, v], el[k, v]
        travel = abs(float(np.angle(np.exp(1j * np.diff(a))).sum()))
        lo, hi = np.percentile(e, [5.0, 95.0])
        extents.append(max(travel, float(hi - lo)))
    return float(np.median(extents)) if extents else float("nan")


def rows_are_scan_lines(grid: np.ndarray, lines: int = 32, points: int = 512) -> bool:
    """Whether an organised cloud ``(H, W, 3)`` (zeros or NaN: no return) has scan lines as rows.

    An organised cloud's rows are scan lines: a spinning sensor's rings (the azimuth goes round
    the circle along a row, the elevation changes by one beam gap from row to row), a
    profiler's lines, a solid-state sensor's wide lines. A driver may also write one firing per
    row (``HEIGHT`` = columns, ``WIDTH`` = beams): a row then covers only the vertical field of
    view and a column the whole circle. The rows are taken as scan lines when a row covers at
    least the angle a column covers (azimuth travel or elevation range, see
    :func:`_line_extent`; measured on up to ``lines`` rows and columns, each sampled at up to
    ``points`` evenly spaced slots)."""
    g = np.asarray(grid)[..., :3]
    H, W = g.shape[:2]
    if H < 2 or W < 2:
        return True

    def pick(n: int, k: int) -> np.ndarray:
        return np.unique(np.linspace(0, n - 1, min(n, k)).astype(np.int64))

    rows = g[pick(H, lines)][:, pick(W, points)].astype(np.float64)
    cols = g[:, pick(W, lines)][pick(H, points)].transpose(1, 0, 2).astype(np.float64)
    along_rows, down_cols = _line_extent(rows), _line_extent(cols)
    if not (np.isfinite(along_rows) and np.isfinite(down_cols)):
        return True  # too few returns to tell: keep the file's organisation
    return along_rows >= down_cols


def sweep_relative(times: np.ndarray) -> bool:
    """True when one sweep's per-point times (s) count from the sweep's start or to its end
    (Ouster ``t``, Livox ``offset_time``: 0 .. period; Velodyne ``time``: -period .. 0) rather
    than on a clock shared by the sweeps: within a second of zero, with one end of the span
    nearer to zero than half the span (a sweep on a shared clock starting at 0 is sweep 0,
    whose start time is then 0 either way)."""
    finite = np.asarray(times, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    if len(finite) == 0:
        return False
    lo, hi = float(finite.min()), float(finite.max())
    if max(abs(lo), abs(hi)) >= 1.0:
        return False
    return min(abs(lo), abs(hi)) <= 0.5 * (hi - lo) + 1e-6


def _pick(fields: dict[str, np.ndarray], names: tuple[str, ...]) -> str | None:
    lower = {k.lower(): k for k in fields}
    return next((lower[n] for n in names if n in lower), None)


# ------------------------------------------------------------------------------------ sequence


class SweepFolder(SequenceBase):
    """A folder of ``.pcd`` / ``.ply`` / ``.bin`` sweeps (sorted by name), or one sweep file
    (also ``.las`` / ``.laz``), organised into Scans (Dataset protocol).

    Parameters
    ----------
    path : the folder, or one file
    rows, cols, altitude, method : passed to the :class:`Organizer` (sensor beams and columns
        when known; default: estimated from the first sweep)
    sweep_period : duration of one sweep (s) when the points carry no times

    Attributes
    ----------
    times : float64 (n,) or None
        From ``times.txt`` when present, else None (per-point times, when the sweeps have them,
        are in each Scan).
    """

    format = "pcd"

    def __init__(
        self,
        path: str | Path,
        *,
        rows: int | None = None,
        cols: int | None = None,
        altitude: np.ndarray | None = None,
        method: str = "auto",
        sweep_period: float = 0.1,
    ) -> None:
        from data_tools.organize import Organizer

        path = Path(path)
        if path.is_dir():
            self.files = sorted(f for f in path.iterdir() if f.is_file() and f.suffix.lower() in SWEEP_SUFFIXES)
            if not self.files:
                raise DataError(f"{path}: no .pcd, .ply or .bin sweeps in the folder")
            kinds = sorted({f.suffix.lower() for f in self.files})
            if len(kinds) > 1:
                log.warning("%s: the folder mixes %s sweeps; all are read, sorted by name", path, "/".join(kinds))
            times_file = path / "times.txt"
        elif path.is_file():
            if path.suffix.lower() not in SINGLE_SUFFIXES:
                raise DataError(f"{path}: unknown sweep format {path.suffix!r} (use {', '.join(SINGLE_SUFFIXES)})")
            self.files = [path]
            times_file = None
        else:
            raise DataError(f"{path}: no such file or directory")
        self.root = path
        self.name = path.stem if path.is_file() else path.name
        self.poses = None
        self.times = None
        if times_file is not None and times_file.is_file():
            from data_tools.formats.kitti import read_times
            from data_tools.formats.trajectory_io import warn_time_gaps

            t = read_times(times_file)
            if len(t) != len(self.files):
                raise DataError(f"{times_file}: {len(t)} times for {len(self.files)} sweeps")
            warn_time_gaps(t, times_file)
            self.times = t
        self.sweep_period = float(sweep_period)
        self._period: float | None = None  # sweep spacing for per-point times relative to each sweep
        self._row_lines: dict[tuple[int, int], bool] = {}  # organised grid shape -> rows are scan lines
        self._clock_warned = False  # per-point times on another clock than times.txt (warned once)
        self._narrow_warned = False  # a float32 time field too narrow for its values (warned once)
        self._units_checked = False  # the first sweep read is checked for metres
        self.organizer = Organizer(
            rows=rows, cols=cols, altitude=altitude, method=method, source_name=str(path), sweep_period=sweep_period
        )

    def _time_resolved(self, values: np.ndarray, name: str) -> bool:
        """False (with one warning) for a floating-point time field too narrow for its values: a
        float32 epoch time (1.7e9 s) has a resolution of 128 s, so every point and every sweep
        would get the same time. Frame times then come from ``times.txt`` or the sweep order."""
        v = np.asarray(values)
        if v.dtype.kind != "f" or v.dtype.itemsize >= 8 or v.size == 0:
            return True
        finite = v[np.isfinite(v)]
        if finite.size == 0:
            return True
        top = float(np.max(np.abs(finite)))
        resolution = float(np.spacing(v.dtype.type(top)))
        if top < 1e4:  # times relative to the sweep (or its end): float32 resolves them to 1 ms
            return True
        # larger values, in an unknown unit: usable when they resolve 1/1000 of the sweep's span
        span = float(finite.max() - finite.min())
        if span > 0 and resolution <= 1e-3 * span:
            return True
        if not self._narrow_warned:
            self._narrow_warned = True
            log.warning(
                "%s: time field %r is %s with values near %.6g: its resolution (%g) cannot time the points; "
                "ignored (frame times from times.txt, else from the sweep order)",
                self.root,
                name,
                v.dtype,
                top,
                resolution,
            )
        return False

    def _relative_period(self, times: np.ndarray, name: str) -> float:
        """The period that spaces sweeps whose per-point times are relative to each sweep (no
        ``times.txt``): ``sweep_period``, or the first such sweep's time span when longer (a slower
        sensor; sweeps cannot overlap). Decided once per folder, with one warning."""
        if self._period is None:
            span = float(np.nanmax(times) - np.nanmin(times))
            self._period = max(self.sweep_period, span) if np.isfinite(span) else self.sweep_period
            if len(self.files) > 1:  # one sweep: its start at 0 s is all there is to say
                log.warning(
                    "%s: per-point times (%r) restart with every sweep and there is no times.txt: sweep i is "
                    "taken to start at i x %g s (put a times.txt with one time per sweep beside them for true times)",
                    self.root,
                    name,
                    self._period,
                )
        return self._period

    def _rows_are_lines(self, xyz: np.ndarray, ring: np.ndarray | None, height: int, width: int, source: str) -> bool:
        """Whether an organised sweep's rows are scan lines (decided once per grid shape, with one
        warning when they are not: its points are then organised as an unorganised cloud, from
        the ring field when it has one, else from the point order or the beams)."""
        key = (height, width)
        if key not in self._row_lines:
            why = None
            if ring is not None and not (ring.reshape(height, width) == ring.reshape(height, width)[:, :1]).all():
                why = "the ring field varies along its rows"
            elif not rows_are_scan_lines(xyz.reshape(height, width, 3)):
                why = "its directions cover less along a row than down a column: one firing per row?"
            self._row_lines[key] = why is None
            if why is not None:
                log.warning(
                    "%s: organised cloud of %d x %d whose rows are not scan lines (%s): organised from its points",
                    source,
                    height,
                    width,
                    why,
                )
        return self._row_lines[key]

    def fields(self, i: int) -> dict[str, np.ndarray]:
        """The raw fields of sweep ``i`` (every point, file order): for writers that keep them."""
        return read_sweep_fields(self.files[i])[0]

    def __getitem__(self, i: int) -> Scan:
        path = self.files[i]
        fields, (height, width) = read_sweep_fields(path)
        src = str(path)
        xyz = np.column_stack([fields["x"], fields["y"], fields["z"]]).astype(np.float64)
        if not self._units_checked:
            self._units_checked = True
            warn_unless_metres(xyz, src)
        ring_name = _pick(fields, RING_FIELDS)
        time_name = _pick(fields, TIME_FIELDS)
        inten_name = _pick(fields, INTENSITY_FIELDS)
        times = None
        if time_name is not None and fields[time_name].ndim == 1 and self._time_resolved(fields[time_name], time_name):
            times, _ = times_in_seconds(fields[time_name], time_name, src)
        frame_time = None
        if self.times is not None:
            frame_time = float(self.times[i])
            if times is not None and float(np.nanmax(times)) < 1.0:  # relative per-point times
                times = times + frame_time
            elif times is not None and abs(float(np.nanmin(times)) - frame_time) > 1.0:
                # per-point times on another clock than times.txt (e.g. epoch s beside times from
                # 0): keep their offsets within the sweep, start the sweep at its times.txt time
                if not self._clock_warned:
                    self._clock_warned = True
                    log.warning(
                        "%s: per-point times (%r, from %.6f s) are on another clock than times.txt (%.6f s): "
                        "each sweep's point times are shifted to start at its times.txt time",
                        src,
                        time_name,
                        float(np.nanmin(times)),
                        frame_time,
                    )
                times = times - float(np.nanmin(times)) + frame_time
        elif times is not None and sweep_relative(times):
            # times from the sweep's start (Ouster t, Livox offset_time) or to its end (Velodyne
            # time <= 0): every sweep would start at the same time; sweep i starts at i periods
            frame_time = i * self._relative_period(times, time_name)
            times = times + frame_time
        elif times is not None:
            frame_time = float(np.nanmin(times))
        else:  # no time at all: sweep i at i periods (its index, not how many sweeps were read before)
            frame_time = i * (self._period or self.sweep_period)
        intensity = None
        if inten_name is not None and fields[inten_name].ndim == 1:
            intensity = np.asarray(fields[inten_name], dtype=np.float32)
        ring = None
        if ring_name is not None and fields[ring_name].ndim == 1:
            ring = np.asarray(fields[ring_name]).astype(np.int64)
        if height > 1 and self._rows_are_lines(xyz, ring, height, width, src):
            grid = xyz.reshape(height, width, 3)
            return self.organizer.scan_organized(
                grid,
                times=None if times is None else times.reshape(height, width),
                intensity=None if intensity is None else intensity.reshape(height, width),
                name=path.stem,
                source=src,
                frame_time=frame_time,
            )
        return self.organizer.scan(
            xyz, ring=ring, times=times, intensity=intensity, name=path.stem, source=src, frame_time=frame_time
        )


def _open(path: Path, options: dict[str, object]) -> SweepFolder:
    return SweepFolder(path, **organiser_hints(options))


def detect(path: Path) -> bool:
    """Sweep files: a ``.pcd`` / ``.ply`` / ``.bin`` file, or a directory holding one."""
    if path.is_dir():
        return any(f.suffix.lower() in SWEEP_SUFFIXES for f in path.iterdir())
    return path.suffix.lower() in SWEEP_SUFFIXES


def detect_las(path: Path) -> bool:
    """A ``.las`` / ``.laz`` file (read as one sweep)."""
    return not path.is_dir() and path.suffix.lower() in (".las", ".laz")


READER = Reader("pcd", ORGANISER_OPTIONS, detect, _open)
LAS_READER = Reader("las", ORGANISER_OPTIONS, detect_las, _open)
