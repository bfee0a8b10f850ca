"""Ray casting (Open3D ``RaycastingScene``) and the noise models of the LiDAR simulator.

Per frame: every slot's ray leaves the sensor pose of its own firing time; the first hit gives
the range and the ground-truth class and instance. Then the configured artefacts are applied
and recorded per slot in ``noise_kind``: glass (no return, or a return from inside), grazing
incidence and low-reflectivity dropouts, ranges beyond the sensor's limits, a dead angle,
Gaussian range noise, mixed pixels at depth discontinuities and background-illumination
outliers (uniform random range, labelled noise).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from data_tools.sim.mesh import FOLIAGE, GLASS, Mesh
from data_tools.sim.scenes import ForestParams, Scene, forest_plot, urban_street
from data_tools.sim.sensors import SimSensor, make_sensor
from data_tools.sim.trajectory import Trajectory, vehicle_trajectory, walking_trajectory
from prc_slam import labels as L

if TYPE_CHECKING:
    import open3d as o3d

# per-slot noise kinds recorded in the ground truth
CLEAN, MIXED, OUTLIER, DROP_GLASS, DROP_GRAZING, DROP_RANGE, DROP_DARK, GLASS_INSIDE, DEAD_ANGLE, MISS = range(10)
NOISE_KINDS = (
    "clean",
    "mixed_pixel",
    "outlier",
    "dropout_glass",
    "dropout_grazing",
    "dropout_range",
    "dropout_reflectivity",
    "glass_inside",
    "dead_angle",
    "no_hit",
)


class NoiseConfig(BaseModel):
    """Artefacts of the simulated sensor; ``None`` takes the sensor's own value."""

    model_config = ConfigDict(extra="forbid")

    range_sigma: float | None = Field(None, ge=0, description="Gaussian range noise (m)")
    mixed_pixel_rate: float | None = Field(None, ge=0, le=1, description="P(mixed range) at a depth jump")
    mixed_jump: float = Field(0.5, gt=0, description="depth jump (m) between neighbours that can mix")
    outlier_rate: float = Field(0.0, ge=0, le=1, description="background-illumination outliers per slot")
    glass_inside: float = Field(0.5, ge=0, le=1, description="P(a ray through glass returns from inside)")
    grazing_start_deg: float = Field(75.0, ge=0, le=90, description="incidence where grazing dropouts begin")
    reflectivity_k: float = Field(4.0, gt=0, description="P(detect) = 1 - exp(-k rho cos(i) (R_max/r)^2)")


class SimConfig(BaseModel):
    """Everything that determines a simulated sequence (same config, same bytes)."""

    model_config = ConfigDict(extra="forbid")

    scene: str = Field("urban", pattern="^(urban|forest|corridor|street)$")
    sensor: str = "hdl64"
    frames: int = Field(200, ge=1)
    seed: int = 0
    wind: float = Field(0.0, ge=0, description="foliage sway amplitude (m)")
    speed: float | None = Field(None, gt=0, description="platform speed (m/s); default by platform")
    stops: int = Field(1, ge=0, description="full stops of a vehicle")
    lines_per_frame: int | None = Field(None, ge=1, description="profiler scan lines per frame")
    clockwise: bool = Field(False, description="spinning sensor turning clockwise (as a Velodyne)")
    noise: NoiseConfig = Field(default_factory=NoiseConfig)


@dataclass
class SimFrame:
    """One simulated frame: the raw range image and its per-slot ground truth."""

    index: int
    ranges: np.ndarray  # float32 (rows, cols), 0 = no return
    intensity: np.ndarray  # float32 (rows, cols)
    labels: np.ndarray  # uint8 (rows, cols)
    instance: np.ndarray  # uint32 (rows, cols)
    noise_kind: np.ndarray  # uint8 (rows, cols)
    slot_times: np.ndarray  # float64 (rows, cols), absolute seconds
    line_times: np.ndarray  # float64 (n_lines,)
    line_poses: np.ndarray  # float64 (n_lines, 4, 4): columns (spinning) or rows (profiler)
    pose: np.ndarray  # float64 (4, 4): sensor pose at the frame's reference (mid) time
    time: float  # reference time (s)
    rays: int  # rays cast (including glass re-casts)


def _scene_mesh_to_o3d(mesh: Mesh, mask: np.ndarray) -> tuple[o3d.t.geometry.RaycastingScene, np.ndarray]:
    import open3d as o3d  # here, not at the top: reading a simulated sequence needs no ray caster

    scene = o3d.t.geometry.RaycastingScene()
    idx = np.flatnonzero(mask).astype(np.int64)
    if len(idx):
        scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles[idx].astype(np.uint32)))
    return scene, idx


class Simulator:
    """Builds the scene, sensor and trajectory of a :class:`SimConfig` and renders frames.

    Frames are independent given their index (the noise of frame ``i`` is drawn from
    ``seed`` and ``i``), so any frame can be rendered on its own, in any order.
    """

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.sensor: SimSensor = make_sensor(config.sensor, config.lines_per_frame, config.clockwise)
        if config.scene == "urban":
            self.scene: Scene = urban_street(config.seed)
        elif config.scene == "corridor":
            from data_tools.sim.corridor import CorridorParams, corridor_tunnel

            run = config.frames * self.sensor.period * (config.speed or 8.33) + 60.0
            self.scene = corridor_tunnel(config.seed, CorridorParams(length=max(400.0, run)))
        elif config.scene == "street":  # parked rows and driving cars
            from data_tools.sim.street import street_scene

            self.scene = street_scene(config.seed)
        else:
            duration = config.frames * self.sensor.period
            length = max(60.0, duration * (config.speed or 1.3) + 30.0)
            self.scene = forest_plot(config.seed, ForestParams(length=length))
        duration = config.frames * self.sensor.period + 0.5
        if self.sensor.platform == "vehicle" and config.scene in ("urban", "corridor", "street"):
            self.trajectory: Trajectory = vehicle_trajectory(
                self.scene,
                duration,
                speed=config.speed or 8.33,
                mount_height=self.sensor.mount_height,
                stops=0 if config.scene == "corridor" else config.stops,  # no stop in a tunnel (corridor.py)
                seed=config.seed,
            )
        else:
            # a walker in the street keeps to the right sidewalk (5-8 m right of the centreline)
            lateral = self.scene.info.get("walk_lateral", -5.95 if config.scene == "urban" else 0.0)
            self.trajectory = walking_trajectory(
                self.scene,
                duration,
                speed=config.speed or 1.3,
                mount_height=self.sensor.mount_height,
                lateral=lateral,
                seed=config.seed,
            )
        mesh = self.scene.mesh
        v = mesh.vertices[mesh.triangles].astype(np.float64)
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        self.normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        self.foliage = mesh.material == FOLIAGE
        moving = self.foliage if config.wind > 0 else np.zeros(mesh.n_triangles, bool)
        self._move = getattr(self.scene, "move", None)  # vehicles driving in the scene (street)
        if self._move is not None:
            moving = moving | self.scene.moving_triangles()
        self._static, self._static_idx = _scene_mesh_to_o3d(mesh, ~moving)
        self._moving_idx = np.flatnonzero(moving)
        if config.wind > 0 and len(self._moving_idx):
            vids = np.unique(mesh.triangles[np.flatnonzero(self.foliage)])
            self._wind_vids = vids
            rng = np.random.default_rng(config.seed + 7)
            inst = np.zeros(len(mesh.vertices), np.uint32)
            inst[mesh.triangles[self._moving_idx].ravel()] = np.repeat(mesh.instance[self._moving_idx], 3)
            self._wind_phase = (inst[vids] * 2.399 % (2 * np.pi)) + rng.normal(0, 0.6, len(vids))
            self._wind_flutter = rng.normal(size=(len(vids), 3)) * 0.3
            self._wind_dir = np.array([np.cos(0.7), np.sin(0.7), 0.0])
        self.dirs = self.sensor.model.directions()
        self.blocked = self.sensor.blocked()

    # ---- geometry ---------------------------------------------------------------------

    def _moving_scene(self, t: float) -> o3d.t.geometry.RaycastingScene | None:
        """Foliage displaced by the wind at time ``t`` (None without wind)."""
        if not len(self._moving_idx):
            return None
        mesh = self.scene.mesh
        verts = mesh.vertices.astype(np.float64).copy()
        a = self.config.wind
        if a > 0:
            sway = a * np.sin(2 * np.pi * 0.4 * t + self._wind_phase)[:, None] * self._wind_dir
            flutter = a * np.sin(2 * np.pi * 1.7 * t + 1.3 * self._wind_phase)[:, None] * self._wind_flutter
            verts[self._wind_vids] += sway + flutter
        if self._move is not None:
            verts = self._move(verts, t)
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor(verts.astype(np.float32)),
            o3d.core.Tensor(mesh.triangles[self._moving_idx].astype(np.uint32)),
        )
        return scene

    def _cast(self, origins: np.ndarray, dirs: np.ndarray, moving) -> tuple[np.ndarray, np.ndarray]:
        """Nearest hit distance and global triangle index (-1: none) of each ray."""
        import open3d as o3d

        rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=1).astype(np.float32))
        out = self._static.cast_rays(rays)
        t = out["t_hit"].numpy().astype(np.float64)
        prim = out["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        tri = np.full(len(t), -1, np.int64)
        tri[hit] = self._static_idx[prim[hit]]
        if moving is not None:
            out2 = moving.cast_rays(rays)
            t2 = out2["t_hit"].numpy().astype(np.float64)
            closer = np.isfinite(t2) & (t2 < t)
            t[closer] = t2[closer]
            tri[closer] = self._moving_idx[out2["primitive_ids"].numpy().astype(np.int64)[closer]]
        t[tri < 0] = np.inf
        return t, tri

    # ---- frames -----------------------------------------------------------------------

    def frame(self, index: int) -> SimFrame:
        """Render frame ``index``."""
        cfg, sensor = self.config, self.sensor
        noise = cfg.noise
        rng = np.random.default_rng([cfg.seed, index, 99])
        rows, cols = sensor.model.rows, sensor.model.cols
        t0 = index * sensor.period
        slot_t = t0 + sensor.slot_times()
        line_t = t0 + sensor.line_times()
        if sensor.model.continuous_rows:
            rot, pos = self.trajectory.poses(slot_t)  # every slot at its own pose
            d_world = (rot @ self.dirs[..., None])[..., 0].reshape(-1, 3)
            origins = pos.reshape(-1, 3)
        else:
            rot_c, pos_c = self.trajectory.poses(line_t)  # one pose per column (all beams fire together)
            d_world = (self.dirs.transpose(1, 0, 2) @ rot_c.transpose(0, 2, 1)).transpose(1, 0, 2).reshape(-1, 3)
            origins = np.broadcast_to(pos_c[None], (rows, cols, 3)).reshape(-1, 3)
        moving = self._moving_scene(t0 + sensor.period / 2)
        t, tri = self._cast(origins, d_world, moving)
        n_rays = len(t)
        kind = np.full(len(t), CLEAN, np.uint8)
        kind[tri < 0] = MISS
        mesh = self.scene.mesh

        # glass: no return, or a return from whatever lies behind (up to three panes)
        for _ in range(3):
            glass = (tri >= 0) & (mesh.material[np.maximum(tri, 0)] == GLASS)
            if not glass.any():
                break
            through = glass & (rng.random(len(t)) < noise.glass_inside)
            stop = glass & ~through
            t[stop], tri[stop], kind[stop] = np.inf, -1, DROP_GLASS
            idx = np.flatnonzero(through)
            if len(idx):
                o2 = origins[idx] + d_world[idx] * (t[idx, None] + 0.01)
                t2, tri2 = self._cast(o2, d_world[idx], moving)
                n_rays += len(idx)
                t[idx] = t[idx] + 0.01 + t2
                tri[idx] = tri2
                kind[idx] = np.where(tri2 >= 0, GLASS_INSIDE, MISS)
        hit = tri >= 0
        safe = np.maximum(tri, 0)
        cos_i = np.abs(np.einsum("ij,ij->i", self.normals[safe], d_world))
        rho = mesh.reflectivity[safe].astype(np.float64)

        def drop(mask: np.ndarray, code: int) -> None:
            nonlocal hit
            mask = mask & hit
            kind[mask] = code
            hit = hit & ~mask

        drop((t > sensor.max_range) | (t < sensor.min_range), DROP_RANGE)
        incidence = np.degrees(np.arccos(np.clip(cos_i, 0, 1)))
        p_graze = np.clip((incidence - noise.grazing_start_deg) / max(90 - noise.grazing_start_deg, 1e-6), 0, 1)
        drop(rng.random(len(t)) < p_graze, DROP_GRAZING)
        p_detect = 1 - np.exp(
            -noise.reflectivity_k * rho * np.maximum(cos_i, 0.05) * (sensor.max_range / np.maximum(t, 1e-3)) ** 2
        )
        drop(rng.random(len(t)) > p_detect, DROP_DARK)
        blocked = self.blocked.ravel()
        kind[blocked] = DEAD_ANGLE
        hit &= ~blocked

        sigma = sensor.range_sigma if noise.range_sigma is None else noise.range_sigma
        ranges = np.where(hit, t + rng.normal(0, sigma, len(t)), 0.0)
        ranges[hit & (ranges <= 0)] = 1e-3
        labels = np.where(hit, mesh.label[safe], L.NO_RETURN).astype(np.uint8)
        instance = np.where(hit, mesh.instance[safe], 0).astype(np.uint32)
        intensity = np.where(
            hit, np.clip(rho * np.maximum(cos_i, 0.05) * 255 * rng.uniform(0.9, 1.1, len(t)), 0, 255), 0.0
        )

        # mixed pixels at depth discontinuities along the scan line: the far slot of a jump
        # returns a range between foreground and background
        r2 = ranges.reshape(rows, cols)
        nxt = np.roll(r2, -1, axis=1)
        jump = (r2 > 0) & (nxt > 0) & (np.abs(r2 - nxt) > noise.mixed_jump)
        if sensor.model.continuous_rows:
            jump[:, -1] = False
        far = np.zeros_like(jump)
        far |= jump & (r2 > nxt)
        far |= np.roll(jump & (nxt > r2), 1, axis=1)
        rate = sensor.mixed_pixel_rate if noise.mixed_pixel_rate is None else noise.mixed_pixel_rate
        mixed = far.ravel() & (rng.random(len(t)) < rate)
        near = np.minimum(r2, nxt)
        near_of = np.where((jump & (r2 > nxt)).ravel(), near.ravel(), np.roll(near, 1, axis=1).ravel())
        u = rng.random(len(t))
        ranges[mixed] = near_of[mixed] + u[mixed] * (ranges[mixed] - near_of[mixed])
        labels[mixed], instance[mixed], kind[mixed] = L.NOISE, 0, MIXED

        # background-illumination outliers: any slot, uniform random range
        out = rng.random(len(t)) < noise.outlier_rate
        ranges[out] = rng.uniform(sensor.min_range, sensor.max_range, int(out.sum()))
        labels[out], instance[out], kind[out] = L.NOISE, 0, OUTLIER
        intensity[out] = rng.uniform(0, 30, int(out.sum()))

        shape = (rows, cols)
        return SimFrame(
            index=index,
            ranges=ranges.reshape(shape).astype(np.float32),
            intensity=intensity.reshape(shape).astype(np.float32),
            labels=labels.reshape(shape),
            instance=instance.reshape(shape),
            noise_kind=kind.reshape(shape),
            slot_times=slot_t,
            line_times=line_t,
            line_poses=self.trajectory.matrices(line_t),
            pose=self.trajectory.matrices(np.array([t0 + sensor.period / 2]))[0],
            time=t0 + sensor.period / 2,
            rays=n_rays,
        )
