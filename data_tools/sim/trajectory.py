"""Platform trajectories along a scene's centreline: a vehicle with stops, or a walker with
sway, bounce and yaw. Poses are sampled densely and interpolated at any time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from data_tools.sim.scenes import Scene

RATE = 200.0  # Hz of the dense pose samples


@dataclass
class Trajectory:
    """Sensor poses over time (world frame).

    Attributes
    ----------
    t : float64 (n,)
        Sample times (s), uniform at ``RATE``.
    position : float64 (n, 3)
    ypr : float64 (n, 3)
        Yaw, pitch, roll (rad, unwrapped).
    """

    t: np.ndarray
    position: np.ndarray
    ypr: np.ndarray
    kind: str

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def poses(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation ``(n, 3, 3)`` and translation ``(n, 3)`` at ``times`` (linear interpolation)."""
        times = np.asarray(times, dtype=np.float64)
        x = np.clip(times * RATE, 0, len(self.t) - 1.000001)
        i = x.astype(np.int64)
        f = (x - i)[..., None]
        pos = self.position[i] * (1 - f) + self.position[i + 1] * f
        ypr = self.ypr[i] * (1 - f) + self.ypr[i + 1] * f
        return rotation_ypr(ypr), pos

    def matrices(self, times: np.ndarray) -> np.ndarray:
        """4x4 poses at ``times``."""
        rot, pos = self.poses(times)
        out = np.tile(np.eye(4), (*np.shape(times), 1, 1))
        out[..., :3, :3] = rot
        out[..., :3, 3] = pos
        return out


def rotation_ypr(ypr: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for ``(..., 3)`` angles."""
    y, p, r = ypr[..., 0], ypr[..., 1], ypr[..., 2]
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def speed_profile(
    duration: float, cruise: float, rng: np.random.Generator, stops: int, accel: float = 1.5, stop_time: float = 2.0
) -> np.ndarray:
    """Speed samples at ``RATE``: cruise with ``stops`` full stops (decelerate, wait, go)."""
    n = int(np.ceil(duration * RATE)) + 2
    t = np.arange(n) / RATE
    v = np.full(n, cruise)
    ramp = cruise / accel
    centres = np.sort(rng.uniform(0.2, 0.85, stops)) * duration if stops else []
    for c in centres:
        d = np.abs(t - c)
        v = np.minimum(v, np.clip((d - stop_time / 2) / ramp, 0, 1) * cruise)
    return v


def vehicle_trajectory(
    scene: Scene,
    duration: float,
    *,
    speed: float = 8.33,
    lane: float = -1.8,
    mount_height: float = 1.73,
    stops: int = 1,
    seed: int = 0,
) -> Trajectory:
    """A car driving along the street's centreline in the right lane at ``speed`` with ``stops``
    stops; pitch and roll follow the road's slope and camber."""
    rng = np.random.default_rng(seed + 101)
    v = speed_profile(duration, speed, rng, stops)
    s = 5.0 + np.concatenate([[0.0], np.cumsum(v[:-1]) / RATE])
    if s[-1] > scene.centerline.length - 5:
        raise ValueError(
            f"{duration:.1f} s at {speed} m/s needs {s[-1]:.0f} m of street; the scene has "
            f"{scene.centerline.length:.0f} m"
        )
    xy, heading, _ = scene.centerline.at(s, lane)
    z = scene.road_height(s, np.full_like(s, lane))
    ds = 0.5
    pitch = -np.arctan2(
        scene.road_height(s + ds, np.full_like(s, lane)) - scene.road_height(s - ds, np.full_like(s, lane)), 2 * ds
    )
    roll = np.arctan2(
        scene.road_height(s, np.full_like(s, lane + 0.5)) - scene.road_height(s, np.full_like(s, lane - 0.5)), 1.0
    )
    yaw = np.unwrap(heading) + 0.004 * np.sin(s / 7.0)
    pos = np.column_stack([xy, z + mount_height])
    t = np.arange(len(s)) / RATE
    return Trajectory(t, pos, np.column_stack([yaw, pitch, roll]), "vehicle")


def walking_trajectory(
    scene: Scene, duration: float, *, speed: float = 1.3, mount_height: float = 1.9, lateral: float = 0.0, seed: int = 0
) -> Trajectory:
    """A person walking along the centreline with step bounce (2 Hz), lateral sway and yaw
    oscillation (1 Hz), starting from rest, at ``mount_height`` above the path's height profile."""
    rng = np.random.default_rng(seed + 202)
    n = int(np.ceil(duration * RATE)) + 2
    t = np.arange(n) / RATE
    v = speed * np.clip(t / 1.0, 0, 1) * (1 + 0.05 * np.sin(2 * np.pi * 0.1 * t + rng.uniform(0, 6)))
    s = 2.0 + np.concatenate([[0.0], np.cumsum(v[:-1]) / RATE])
    if s[-1] > scene.centerline.length - 2:
        raise ValueError(
            f"{duration:.1f} s of walking needs {s[-1]:.0f} m of path; the scene has {scene.centerline.length:.0f} m"
        )
    phase = rng.uniform(0, 2 * np.pi)
    sway = 0.04 * np.sin(2 * np.pi * 1.0 * t + phase)
    xy, heading, zc = scene.centerline.at(s, lateral + sway)
    bounce = 0.03 * np.sin(2 * np.pi * 2.0 * t + 2 * phase)
    yaw = np.unwrap(heading) + np.radians(3.0) * np.sin(2 * np.pi * 1.0 * t + phase + 0.5)
    pitch = np.radians(2.0) * np.sin(2 * np.pi * 2.0 * t + phase)
    roll = np.radians(2.0) * np.sin(2 * np.pi * 1.0 * t + phase)
    pos = np.column_stack([xy, zc + mount_height + bounce])
    return Trajectory(t, pos, np.column_stack([yaw, pitch, roll]), "walking")


def flight_line(
    start: tuple[float, float],
    heading: float,
    length: float,
    altitude: float,
    speed: float,
    *,
    attitude_sigma_deg: float = 0.02,
    seed: int = 0,
) -> Trajectory:
    """An aircraft on a straight survey line from ``start`` (x, y) along ``heading`` (rad) at
    constant ``altitude`` (m, world z) and ``speed``; roll and pitch oscillate slowly (0.5 deg,
    turbulence) and the yaw carries a small crab angle, as an inertial system measures them;
    ``attitude_sigma_deg`` adds the residual (unmeasured) attitude noise."""
    rng = np.random.default_rng(seed + 303)
    duration = length / speed
    n = int(np.ceil(duration * RATE)) + 2
    t = np.arange(n) / RATE
    s = speed * t
    pos = np.column_stack([start[0] + s * np.cos(heading), start[1] + s * np.sin(heading), np.full(n, altitude)])
    phase = rng.uniform(0, 2 * np.pi, 3)
    crab = np.radians(rng.uniform(-2, 2))
    sigma = np.radians(attitude_sigma_deg)
    yaw = heading + crab + np.radians(0.3) * np.sin(2 * np.pi * 0.05 * t + phase[0]) + rng.normal(0, sigma, n)
    pitch = np.radians(0.5) * np.sin(2 * np.pi * 0.1 * t + phase[1]) + rng.normal(0, sigma, n)
    roll = np.radians(0.5) * np.sin(2 * np.pi * 0.07 * t + phase[2]) + rng.normal(0, sigma, n)
    return Trajectory(t, pos, np.column_stack([yaw, pitch, roll]), "aircraft")
