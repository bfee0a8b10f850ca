"""Writers: per-frame label files and classified LAS 1.4 clouds."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import laspy
import numpy as np

from data_tools.errors import DataError
from data_tools.formats.laz import laz_backend
from prc_slam import labels as L


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary name beside ``path``, renamed to ``path`` when the block ends without error (a
    write cut by Ctrl-C, a full disk or a crash never leaves a short file under the final name)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.partial{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_label_file(path: str | Path, codes: np.ndarray) -> None:
    """Write one ``.label`` file: ``uint32`` per point, our code in the lower 16 bits (atomically)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        L.to_label_file(codes).tofile(tmp)


def write_las(
    path: str | Path,
    xyz: np.ndarray,
    classification: np.ndarray,
    *,
    intensity: np.ndarray | None = None,
    point_source_id: np.ndarray | None = None,
    gps_time: np.ndarray | None = None,
) -> None:
    """Write a LAS 1.4 file (point format 6) with our codes in ``classification``; LAZ-compressed
    (lazrs) when ``path`` ends in ``.laz``.

    Parameters
    ----------
    xyz : float (N, 3)
    classification : uint8 (N,)
    intensity : optional (N,), scaled into uint16 when given as floats in [0, 1] or [0, 255]
    point_source_id : optional (N,), e.g. the frame index
    gps_time : optional (N,), seconds
    """
    path = Path(path)
    xyz = np.asarray(xyz, dtype=np.float64)
    classification = np.asarray(classification)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DataError(f"{path}: xyz must be (N, 3), got {xyz.shape}")
    if classification.shape != (len(xyz),):
        raise DataError(f"{path}: {classification.size} classes for {len(xyz)} points")
    if not np.isfinite(xyz).all():
        raise DataError(f"{path}: refusing to write non-finite coordinates")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = xyz.min(axis=0) if len(xyz) else np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = classification.astype(np.uint8)
    if intensity is not None:
        inten = np.asarray(intensity, dtype=np.float64)
        scale = 65535.0 / max(float(inten.max()), 1.0) if len(inten) else 1.0
        las.intensity = np.clip(inten * scale, 0, 65535).astype(np.uint16)
    if point_source_id is not None:
        las.point_source_id = np.asarray(point_source_id, dtype=np.uint16)
    if gps_time is not None:
        las.gps_time = np.asarray(gps_time, dtype=np.float64)
    with atomic_path(path) as tmp:
        las.write(tmp, do_compress=path.suffix.lower() == ".laz", laz_backend=laz_backend(path))


def write_ply(path: str | Path, xyz: np.ndarray, labels: np.ndarray | None = None) -> None:
    """Binary little-endian PLY with float32 x, y, z and an optional uint8 ``label`` per vertex."""
    path = Path(path)
    xyz = np.asarray(xyz, dtype=np.float32)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DataError(f"{path}: xyz must be (N, 3), got {xyz.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if labels is not None:
        labels = np.asarray(labels)
        if labels.shape != (len(xyz),):
            raise DataError(f"{path}: {labels.size} labels for {len(xyz)} points")
        fields.append(("label", "u1"))
    rec = np.empty(len(xyz), dtype=fields)
    rec["x"], rec["y"], rec["z"] = xyz.T
    if labels is not None:
        rec["label"] = labels
    props = "".join(f"property {'float' if t == '<f4' else 'uchar'} {n}\n" for n, t in fields)
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(xyz)}\n{props}end_header\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())


class ClassSplitWriter:
    """Segregation into sub-clouds (paper 004): one combined LAS 1.4 file with every point and
    one LAS 1.4 file per class present (``<class name>.las``), written chunk by chunk. When the
    combined name ends in ``.laz`` every file is LAZ-compressed (``<class name>.laz``). ``crs``:
    the input's coordinate reference system records, written in every file; ``grid``: the input's
    ``(scales, offsets)`` (a LAS input's, :func:`data_tools.formats.clouds.cloud_grid`), so that every
    point keeps its stored coordinates (default: 1 mm from the first chunk's minimum).

    Use as a context manager; ``write(xyz, codes)`` may be called any number of times.
    """

    def __init__(
        self,
        out_dir: str | Path,
        combined: str = "map_classified.las",
        crs: list | None = None,
        grid: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.combined_name = combined
        self.crs = list(crs or [])  # the input's CRS VLRs (data_tools.formats.clouds.cloud_crs), written in every file
        self.grid = grid
        self._writers: dict[str, laspy.LasWriter] = {}
        self._header: laspy.LasHeader | None = None
        self.counts: dict[str, int] = {}
        #: points without finite coordinates (no return), which LAS cannot store: not written
        self.skipped = 0

    def __enter__(self) -> ClassSplitWriter:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.remove_earlier()
        return self

    def remove_earlier(self) -> list[Path]:
        """Delete the files an earlier split into the same folder wrote (combined and per class,
        LAS or LAZ): a class this run does not find kept its old file, and the folder said that
        class was there. Returns the files removed."""
        stems = {Path(self.combined_name).stem, *L.CODE_TO_NAME.values()}
        old = [
            f
            for f in self.out_dir.iterdir()
            if f.is_file()
            and f.suffix.lower() in (".las", ".laz")
            and (f.stem in stems or (f.stem.startswith("code_") and f.stem[5:].isdigit()))
        ]
        for f in old:
            f.unlink()
        return old

    def __exit__(self, *exc: object) -> None:
        for w in self._writers.values():
            w.close()
        self._writers.clear()

    @property
    def paths(self) -> dict[str, Path]:
        """File per sub-cloud written so far (``"all"`` for the combined one)."""
        return {k: self._path(k) for k in self.counts}

    def _path(self, name: str) -> Path:
        suffix = ".laz" if self.combined_name.lower().endswith(".laz") else ".las"
        return self.out_dir / (self.combined_name if name == "all" else f"{name}{suffix}")

    def _writer(self, name: str) -> laspy.LasWriter:
        if name not in self._writers:
            path = self._path(name)
            compress = path.suffix.lower() == ".laz"
            self._writers[name] = laspy.open(
                path, mode="w", header=self._header, do_compress=compress, laz_backend=laz_backend(path)
            )
        return self._writers[name]

    def write(self, xyz: np.ndarray, codes: np.ndarray) -> None:
        xyz = np.asarray(xyz, dtype=np.float64)
        codes = np.asarray(codes, dtype=np.uint8)
        if xyz.ndim != 2 or xyz.shape[1] != 3 or codes.shape != (len(xyz),):
            raise DataError(f"{self.out_dir}: {codes.shape} codes for points of shape {xyz.shape}")
        ok = np.isfinite(xyz).all(axis=1)  # non-finite points carry no_return and no coordinates
        self.skipped += int(len(ok) - np.count_nonzero(ok))
        xyz, codes = xyz[ok], codes[ok]
        if len(xyz) == 0:
            return
        if self._header is None:
            self._header = laspy.LasHeader(point_format=6, version="1.4")
            if self.grid is not None:
                self._header.scales = np.asarray(self.grid[0], np.float64)
                self._header.offsets = np.asarray(self.grid[1], np.float64)
            else:
                self._header.scales = np.array([0.001, 0.001, 0.001])
                self._header.offsets = np.floor(xyz.min(axis=0))
            for vlr in self.crs:
                self._header.vlrs.append(vlr)
            if any(type(v).__name__ == "WktCoordinateSystemVlr" for v in self.crs):
                self._header.global_encoding.wkt = True
        for name, sel in [("all", slice(None))] + [
            (L.CODE_TO_NAME.get(int(c), f"code_{c}"), codes == c) for c in np.unique(codes)
        ]:
            rec = laspy.ScaleAwarePointRecord.zeros(len(codes[sel]), header=self._header)
            rec.x, rec.y, rec.z = xyz[sel, 0], xyz[sel, 1], xyz[sel, 2]
            rec.classification = codes[sel]
            self._writer(name).write_points(rec)
            self.counts[name] = self.counts.get(name, 0) + len(rec)
