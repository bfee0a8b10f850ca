"""Airborne (``als``) and terrestrial (``tls``) laser scanning of the simulator's scenes.

Both produce an unorganised point cloud with per-point ground truth, as such sensors deliver
them (LAS/LAZ tiles), rather than the range-image stream of the mobile sensors:

* ``als``: an aircraft flies parallel flight lines (serpentine, with side overlap) over the
  scene at ``altitude``; a line scanner sweeps across track over ``fov_deg`` and looks
  ``tilt_deg`` forward (an oblique look that also samples facades). The pulse rate follows from
  the requested single-pass density (points/m^2). A pulse that hits foliage (or a branch)
  continues with probability ``foliage_pass`` and can give up to ``max_returns`` returns, each
  at least ``min_separation`` behind the last (the receiver's dead time); glass is passed
  without a return. Outliers (birds, multipath "low points") are labelled noise.
* ``tls``: a static scanner on a tripod at one or more stations: full azimuth turn, elevation
  from ``elevation_deg[0]`` to ``[1]`` at ``step_deg`` in both angles, first returns only by
  default, range noise and a maximum range.

Ground truth per point: the class code (``prc_slam.labels``) and instance of the surface hit,
the return number and number of returns of its pulse, the flight line or station, the time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from data_tools.errors import DataError
from data_tools.sim.mesh import FOLIAGE, GLASS
from data_tools.sim.scenes import ForestParams, Scene, forest_plot, urban_street
from data_tools.sim.trajectory import flight_line
from prc_slam import labels as L

#: chunk of pulses cast at once (bounds the memory of the per-pulse rotations)
CHUNK = 400_000


class ALSConfig(BaseModel):
    """An airborne survey of a simulated scene (same config, same cloud)."""

    model_config = ConfigDict(extra="forbid")

    scene: str = Field("urban", pattern="^(urban|forest)$")
    seed: int = 0
    density: float = Field(8.0, gt=0, le=200, description="single-pass pulse density on flat ground (1/m^2)")
    altitude: float = Field(400.0, gt=10, description="flying height above the scene's mean height (m)")
    speed: float = Field(60.0, gt=0, description="ground speed (m/s)")
    fov_deg: float = Field(40.0, gt=0, lt=120, description="full across-track scan angle (deg)")
    tilt_deg: float = Field(8.0, ge=0, lt=45, description="forward look of the scan plane (deg)")
    scan_rate: float = Field(120.0, gt=0, description="scan lines per second (Hz)")
    overlap: float = Field(0.3, ge=0, lt=0.9, description="side overlap of neighbouring flight lines")
    max_returns: int = Field(4, ge=1, le=15)
    min_separation: float = Field(1.5, ge=0, description="smallest distance between returns of a pulse (m)")
    foliage_pass: float = Field(0.6, ge=0, le=1, description="P(a pulse goes on after a foliage or branch hit)")
    range_sigma: float = Field(0.03, ge=0, description="Gaussian range noise (m)")
    attitude_sigma_deg: float = Field(0.02, ge=0, description="residual attitude error of the trajectory (deg)")
    outlier_rate: float = Field(2e-4, ge=0, le=0.1, description="outliers (birds, low points) per pulse")
    region: tuple[float, float, float, float] | None = Field(None, description="x0, y0, x1, y1 to survey (m)")
    forest_length: float = Field(200.0, gt=10, description="forest scene: strip length (m)")
    forest_width: float = Field(100.0, gt=10, description="forest scene: strip width (m)")


class TLSConfig(BaseModel):
    """A terrestrial (static) scan of a simulated scene."""

    model_config = ConfigDict(extra="forbid")

    scene: str = Field("forest", pattern="^(urban|forest)$")
    seed: int = 0
    stations: int = Field(3, ge=1, le=50, description="scan positions along the scene's path")
    spacing: float = Field(15.0, gt=0, description="distance between stations along the path (m)")
    start: float = Field(15.0, ge=0, description="path position of the first station (m)")
    height: float = Field(1.5, gt=0, description="scanner height above the path (m)")
    step_deg: float = Field(0.2, gt=0.005, le=5, description="angular step in azimuth and elevation (deg)")
    elevation_deg: tuple[float, float] = Field((-60.0, 90.0), description="lowest and highest beam (deg)")
    max_range: float = Field(80.0, gt=0)
    range_sigma: float = Field(0.005, ge=0, description="Gaussian range noise (m)")
    max_returns: int = Field(1, ge=1, le=15)
    min_separation: float = Field(1.0, ge=0)
    foliage_pass: float = Field(0.3, ge=0, le=1)
    outlier_rate: float = Field(1e-4, ge=0, le=0.1)
    forest_length: float = Field(60.0, gt=10, description="forest scene: strip length (m)")
    forest_width: float = Field(60.0, gt=10, description="forest scene: strip width (m)")


@dataclass
class SimCloud:
    """A simulated point cloud with per-point ground truth, in acquisition order."""

    points: np.ndarray  # float64 (N, 3), world frame
    labels: np.ndarray  # uint8 (N,), class code of the surface hit (noise for outliers)
    instance: np.ndarray  # uint32 (N,)
    return_number: np.ndarray  # uint8 (N,), 1-based
    number_of_returns: np.ndarray  # uint8 (N,)
    source: np.ndarray  # uint16 (N,), flight line or station
    time: np.ndarray  # float64 (N,), s
    intensity: np.ndarray  # float32 (N,), 0-255
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)


class _Caster:
    """Open3D ray casting on a scene mesh with the per-triangle truth."""

    def __init__(self, scene: Scene) -> None:
        from data_tools.sim.simulator import _scene_mesh_to_o3d

        self.mesh = scene.mesh
        self.o3d, self.idx = _scene_mesh_to_o3d(scene.mesh, np.ones(scene.mesh.n_triangles, bool))
        v = scene.mesh.vertices[scene.mesh.triangles].astype(np.float64)
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        self.normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import open3d as o3d

        rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=1).astype(np.float32))
        out = self.o3d.cast_rays(rays)
        t = out["t_hit"].numpy().astype(np.float64)
        prim = out["primitive_ids"].numpy().astype(np.int64)
        tri = np.where(np.isfinite(t), self.idx[np.minimum(prim, len(self.idx) - 1)], -1)
        t[tri < 0] = np.inf
        return t, tri


def _returns(
    caster: _Caster,
    origins: np.ndarray,
    dirs: np.ndarray,
    rng: np.random.Generator,
    max_returns: int,
    min_separation: float,
    foliage_pass: float,
    range_sigma: float,
    max_range: float = np.inf,
) -> dict[str, np.ndarray]:
    """Cast pulses and follow them through foliage; one row per return, by pulse then return.

    Returns dict of ``pulse``, ``xyz``, ``label``, ``instance``, ``ret`` (1-based), ``nret``,
    ``intensity``; a pulse without a hit gives no row.
    """
    mesh = caster.mesh
    n = len(origins)
    o = np.asarray(origins, np.float64).copy()
    d = np.asarray(dirs, np.float64)
    travelled = np.zeros(n)
    alive = np.arange(n)
    count = np.zeros(n, np.int64)
    rows: list[tuple[np.ndarray, ...]] = []
    for _ in range(max_returns + 4):  # + glass panes passed without a return
        if not len(alive):
            break
        t, tri = caster.cast(o[alive], d[alive])
        hit = (tri >= 0) & (travelled[alive] + t <= max_range)
        alive, t, tri = alive[hit], t[hit], tri[hit]
        glass = mesh.material[tri] == GLASS
        # glass: no return, the pulse goes on behind the pane
        g = alive[glass]
        o[g] += d[g] * (t[glass, None] + 0.01)
        travelled[g] += t[glass] + 0.01
        solid = ~glass
        a, ts, tr = alive[solid], t[solid], tri[solid]
        r = ts + rng.normal(0, range_sigma, len(ts))
        xyz = o[a] + d[a] * r[:, None]
        cos_i = np.abs(np.einsum("ij,ij->i", caster.normals[tr], d[a]))
        inten = np.clip(mesh.reflectivity[tr] * np.maximum(cos_i, 0.05) * 255 * rng.uniform(0.9, 1.1, len(a)), 0, 255)
        count[a] += 1
        rows.append((a, xyz, mesh.label[tr], mesh.instance[tr], count[a].copy(), inten))
        porous = (mesh.material[tr] == FOLIAGE) | (mesh.label[tr] == L.VEGETATION)
        go = porous & (rng.random(len(a)) < foliage_pass) & (count[a] < max_returns)
        nxt = a[go]
        step = ts[go] + max(min_separation, 0.01)
        o[nxt] += d[nxt] * step[:, None]
        travelled[nxt] += step
        alive = np.concatenate([g, nxt])
    if not rows:
        z = np.zeros(0)
        return {"pulse": z.astype(np.int64), "xyz": np.zeros((0, 3)), "label": z.astype(np.uint8),
                "instance": z.astype(np.uint32), "ret": z.astype(np.uint8), "nret": z.astype(np.uint8),
                "intensity": z.astype(np.float32)}  # fmt: skip
    pulse, xyz, label, inst, ret, inten = (np.concatenate(c) for c in zip(*rows, strict=True))
    order = np.lexsort((ret, pulse))
    pulse, ret = pulse[order], ret[order]
    return {
        "pulse": pulse,
        "xyz": xyz[order],
        "label": label[order].astype(np.uint8),
        "instance": inst[order].astype(np.uint32),
        "ret": ret.astype(np.uint8),
        "nret": count[pulse].astype(np.uint8),
        "intensity": inten[order].astype(np.float32),
    }


def _outliers(
    rows: dict[str, np.ndarray], rng: np.random.Generator, rate: float, n_pulses: int, origins, dirs, times
) -> dict[str, np.ndarray]:
    """Replace the returns of ``rate`` of the pulses by one outlier each: half high (a bird or
    haze, a random range short of the surface), half low (multipath, 1-8 m below it)."""
    bad = np.flatnonzero(rng.random(n_pulses) < rate)
    if not len(bad) or not len(rows["pulse"]):
        return rows
    first = np.searchsorted(rows["pulse"], bad)
    ok = (first < len(rows["pulse"])) & (rows["pulse"][np.minimum(first, len(rows["pulse"]) - 1)] == bad)
    bad, first = bad[ok], first[ok]
    surface = np.linalg.norm(rows["xyz"][first] - origins[bad], axis=1)
    high = rng.random(len(bad)) < 0.5
    rng_out = np.where(high, surface * rng.uniform(0.2, 0.9, len(bad)), surface + rng.uniform(1.0, 8.0, len(bad)))
    keep = ~np.isin(rows["pulse"], bad)
    out = {k: v[keep] for k, v in rows.items()}
    extra = {
        "pulse": bad,
        "xyz": origins[bad] + dirs[bad] * rng_out[:, None],
        "label": np.full(len(bad), L.NOISE, np.uint8),
        "instance": np.zeros(len(bad), np.uint32),
        "ret": np.ones(len(bad), np.uint8),
        "nret": np.ones(len(bad), np.uint8),
        "intensity": rng.uniform(0, 30, len(bad)).astype(np.float32),
    }
    merged = {k: np.concatenate([out[k], extra[k]]) for k in out}
    order = np.lexsort((merged["ret"], merged["pulse"]))
    return {k: v[order] for k, v in merged.items()}


def _scene(kind: str, seed: int, length: float, width: float) -> Scene:
    if kind == "urban":
        return urban_street(seed)
    return forest_plot(seed, ForestParams(length=length, width=width))


def simulate_als(config: ALSConfig, scene: Scene | None = None) -> SimCloud:
    """Fly the survey of ``config`` over its scene (or ``scene``) and return the cloud."""
    cfg = config
    scene = scene or _scene(cfg.scene, cfg.seed, cfg.forest_length, cfg.forest_width)
    caster = _Caster(scene)
    rng = np.random.default_rng([cfg.seed, 4242])
    v = scene.mesh.vertices
    if cfg.region is None:
        x0, y0 = v[:, :2].min(axis=0)
        x1, y1 = v[:, :2].max(axis=0)
    else:
        x0, y0, x1, y1 = cfg.region
        if x1 <= x0 or y1 <= y0:
            raise DataError(f"ALS region {cfg.region}: needs x0 < x1 and y0 < y1")
    z_ref = float(np.median(v[:, 2]))
    H = cfg.altitude
    half = np.radians(cfg.fov_deg / 2)
    swath = 2 * H * np.tan(half)
    dx = cfg.speed / cfg.scan_rate  # along-track line spacing
    per_line = max(int(np.ceil(cfg.density * swath * dx)), 2)
    spacing = swath * (1 - cfg.overlap)
    n_lines = max(int(np.ceil((y1 - y0) / spacing)), 1)
    ys = y0 + (np.arange(n_lines) + 0.5) * (y1 - y0) / n_lines
    lead = H * np.tan(np.radians(cfg.tilt_deg)) + 20.0  # the forward look reaches ahead of the aircraft
    length = x1 - x0 + 2 * lead
    duration = length / cfg.speed
    n_scan = int(duration * cfg.scan_rate)
    scan_angle = np.linspace(-half, half, per_line)
    tilt = np.radians(cfg.tilt_deg)
    # body frame: x forward, y left, z up; the scan plane tilted forward about y
    body = np.column_stack([np.sin(tilt) * np.cos(scan_angle), np.sin(scan_angle), -np.cos(tilt) * np.cos(scan_angle)])
    parts: list[dict[str, np.ndarray]] = []
    t_offset = 0.0
    n_pulses_total = 0
    for k, y in enumerate(ys):
        forward = k % 2 == 0
        start = (x0 - lead, y) if forward else (x1 + lead, y)
        traj = flight_line(
            start, 0.0 if forward else np.pi, length, z_ref + H, cfg.speed,
            attitude_sigma_deg=cfg.attitude_sigma_deg, seed=cfg.seed * 1000 + k,
        )  # fmt: skip
        n_pulse = n_scan * per_line
        for c0 in range(0, n_pulse, CHUNK):
            ids = np.arange(c0, min(c0 + CHUNK, n_pulse))
            line, col = np.divmod(ids, per_line)
            times = (line + (col + 0.5) / per_line) / cfg.scan_rate
            rot, pos = traj.poses(times)
            dirs = np.einsum("nij,nj->ni", rot, body[col])
            rows = _returns(caster, pos, dirs, rng, cfg.max_returns, cfg.min_separation, cfg.foliage_pass,
                            cfg.range_sigma)  # fmt: skip
            rows = _outliers(rows, rng, cfg.outlier_rate, len(ids), pos, dirs, times)
            inside = (rows["xyz"][:, 0] >= x0) & (rows["xyz"][:, 0] < x1)
            inside &= (rows["xyz"][:, 1] >= y0) & (rows["xyz"][:, 1] < y1)
            rows = {kk: vv[inside] for kk, vv in rows.items()}
            rows["time"] = t_offset + times[rows["pulse"]]
            rows["source"] = np.full(len(rows["pulse"]), k, np.uint16)
            parts.append(rows)
        n_pulses_total += n_pulse
        t_offset += duration + 30.0  # the turn between lines
    cloud = _assemble(parts)
    cloud.meta = {
        "sensor": "als",
        "config": cfg.model_dump(mode="json"),
        "scene": {"kind": scene.kind, "seed": scene.seed},
        "region": [float(x0), float(y0), float(x1), float(y1)],
        "flight_lines": n_lines,
        "swath_m": swath,
        "pulses_per_line": per_line,
        "pulse_rate_hz": per_line * cfg.scan_rate,
        "pulses": n_pulses_total,
    }
    return cloud


def _station_height(caster: _Caster, xy: np.ndarray) -> np.ndarray:
    """Terrain height below each x-y (the lowest surface a vertical ray finds)."""
    o = np.column_stack([xy, np.full(len(xy), 1e4)])
    d = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    z = np.full(len(xy), np.nan)
    for _ in range(30):
        t, tri = caster.cast(o, d)
        hit = tri >= 0
        if not hit.any():
            break
        ground = hit & np.isin(caster.mesh.label[np.maximum(tri, 0)], (L.GROUND, L.CURB))
        z[ground & np.isnan(z)] = o[ground & np.isnan(z), 2] - t[ground & np.isnan(z)]
        o[hit] = o[hit] + d[hit] * (t[hit, None] + 0.01)
        if np.isfinite(z).all():
            break
    if np.isnan(z).any():
        raise DataError(f"TLS station(s) at {xy[np.isnan(z)].tolist()}: no ground below")
    return z


def simulate_tls(config: TLSConfig, scene: Scene | None = None) -> SimCloud:
    """Scan the scene of ``config`` (or ``scene``) from its stations and return the cloud."""
    cfg = config
    scene = scene or _scene(cfg.scene, cfg.seed, cfg.forest_length, cfg.forest_width)
    caster = _Caster(scene)
    rng = np.random.default_rng([cfg.seed, 5151])
    s = cfg.start + cfg.spacing * np.arange(cfg.stations)
    if s[-1] > scene.centerline.length:
        raise DataError(
            f"TLS: {cfg.stations} stations {cfg.spacing} m apart from {cfg.start} m need {s[-1]:.0f} m of path; "
            f"the scene has {scene.centerline.length:.0f} m"
        )
    xy, _, _ = scene.centerline.at(s, 0.0)
    z = _station_height(caster, np.asarray(xy, np.float64)) + cfg.height
    step = np.radians(cfg.step_deg)
    az = np.arange(0, 2 * np.pi, step)
    el = np.arange(np.radians(cfg.elevation_deg[0]), np.radians(cfg.elevation_deg[1]) + 1e-9, step)
    if cfg.elevation_deg[0] >= cfg.elevation_deg[1]:
        raise DataError(f"TLS elevation range {cfg.elevation_deg}: lowest must be below highest")
    A, E = np.meshgrid(az, el, indexing="ij")  # column by column, as the head turns
    dirs_all = np.column_stack([(np.cos(E) * np.cos(A)).ravel(), (np.cos(E) * np.sin(A)).ravel(), np.sin(E).ravel()])
    per_station = len(dirs_all)
    scan_time = 60.0  # s per station
    parts = []
    for k in range(cfg.stations):
        origin = np.array([xy[k, 0], xy[k, 1], z[k]])
        for c0 in range(0, per_station, CHUNK):
            dirs = dirs_all[c0 : c0 + CHUNK]
            pos = np.broadcast_to(origin, dirs.shape)
            rows = _returns(caster, pos, dirs, rng, cfg.max_returns, cfg.min_separation, cfg.foliage_pass,
                            cfg.range_sigma, cfg.max_range)  # fmt: skip
            times = k * (scan_time + 120.0) + (c0 + np.arange(len(dirs))) / per_station * scan_time
            rows = _outliers(rows, rng, cfg.outlier_rate, len(dirs), pos, dirs, times)
            rows["time"] = times[rows["pulse"]]
            rows["source"] = np.full(len(rows["pulse"]), k, np.uint16)
            parts.append(rows)
    cloud = _assemble(parts)
    cloud.meta = {
        "sensor": "tls",
        "config": cfg.model_dump(mode="json"),
        "scene": {"kind": scene.kind, "seed": scene.seed},
        "stations": [[float(a), float(b), float(c)] for a, b, c in zip(xy[:, 0], xy[:, 1], z, strict=True)],
        "pulses_per_station": per_station,
    }
    return cloud


def _assemble(parts: list[dict[str, np.ndarray]]) -> SimCloud:
    def cat(key, dtype, width=None):
        if not parts:
            return np.zeros((0, width) if width else 0, dtype)
        return np.concatenate([p[key] for p in parts]).astype(dtype)

    return SimCloud(
        points=cat("xyz", np.float64, 3),
        labels=cat("label", np.uint8),
        instance=cat("instance", np.uint32),
        return_number=cat("ret", np.uint8),
        number_of_returns=cat("nret", np.uint8),
        source=cat("source", np.uint16),
        time=cat("time", np.float64),
        intensity=cat("intensity", np.float32),
    )


def areal_density(points: np.ndarray, cell: float = 1.0) -> float:
    """Median points per m^2 over the occupied ``cell`` x ``cell`` columns (a survey's density)."""
    if len(points) == 0:
        return 0.0
    _, counts = np.unique(np.floor(points[:, :2] / cell).astype(np.int64), axis=0, return_counts=True)
    return float(np.median(counts)) / cell**2


def write_cloud(cloud: SimCloud, path: str | Path) -> Path:
    """Write the cloud as LAS 1.4 / LAZ (by suffix; point format 6): the true class in
    ``classification`` (our codes, ASPRS where ASPRS has the class), returns, ``gps_time``,
    ``point_source_id`` = flight line or station, ``intensity``, and an extra ``instance``
    dimension; the simulation's metadata goes to ``<path>.json``."""
    import json

    import laspy

    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        raise DataError(f"{path}: simulated clouds are written as .las or .laz")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(cloud.points.min(axis=0)) if len(cloud) else np.zeros(3)
    header.add_extra_dim(laspy.ExtraBytesParams(name="instance", type=np.uint32))
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.points.T
    las.classification = cloud.labels
    las.return_number = np.minimum(cloud.return_number, 15)
    las.number_of_returns = np.minimum(cloud.number_of_returns, 15)
    las.point_source_id = cloud.source
    las.gps_time = cloud.time
    las.intensity = (cloud.intensity * 257).astype(np.uint16)
    las.instance = cloud.instance
    path.parent.mkdir(parents=True, exist_ok=True)
    from data_tools.formats.laz import laz_backend

    try:
        las.write(path, do_compress=path.suffix.lower() == ".laz", laz_backend=laz_backend(path))
    except laspy.LaspyException as exc:
        raise DataError(f"{path}: cannot write ({exc})") from exc
    Path(str(path) + ".json").write_text(json.dumps(cloud.meta, indent=2) + "\n")
    return path


def read_truth(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Class codes (``classification``) and, when present, the ``instance`` dimension of a
    LAS/LAZ file, e.g. a simulated cloud's truth or a public tile's own classes."""
    import laspy

    path = Path(path)
    try:
        las = laspy.read(path)
    except (laspy.LaspyException, ValueError, OSError) as exc:
        raise DataError(f"{path}: not a readable LAS file ({exc})") from exc
    inst = np.asarray(las["instance"], np.uint32) if "instance" in las.point_format.dimension_names else None
    return np.asarray(las.classification, np.uint8), inst


def simulate_cloud(
    sensor: str, scene: str = "urban", seed: int = 0, density: float | None = None, out: str | Path | None = None
) -> tuple[SimCloud, Path | None]:
    """``als`` or ``tls`` over ``scene`` with default settings (``density``: the ALS single-pass
    density, points/m^2); written to ``out`` when given (a ``.las``/``.laz`` file, or a
    directory that gets ``<sensor>_<scene>_<seed>.laz``)."""
    if sensor == "als":
        cloud = simulate_als(ALSConfig(scene=scene, seed=seed, **({} if density is None else {"density": density})))
    elif sensor == "tls":
        if density is not None:
            raise DataError("--density is the airborne pulse density; the TLS sets its angular step instead")
        cloud = simulate_tls(TLSConfig(scene=scene, seed=seed))
    else:
        raise DataError(f"unknown cloud sensor {sensor!r}; choose als or tls")
    if out is None:
        return cloud, None
    out = Path(out)
    if out.suffix.lower() not in (".las", ".laz"):
        out = out / f"{sensor}_{scene}_{seed}.laz"
    return cloud, write_cloud(cloud, out)
