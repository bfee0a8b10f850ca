"""Simulated sensors: scan pattern, timing and mounting of each, as a SensorModel.

Every slot is fired at its own time; the simulator takes the sensor pose of that time, so a
moving platform produces real motion distortion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prc_slam.scan import ProfilerSensor, SensorModel, SpinningSensor


def _rot(axis: str, deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


@dataclass(frozen=True)
class SimSensor:
    """A sensor of the simulator.

    Attributes
    ----------
    name : str
    model : SensorModel
        Geometry of one frame (rows x cols).
    period : float
        Seconds per frame (spinning: one sweep; profiler: ``rows`` scan lines).
    mount_height : float
        Height of the sensor above the ground contact of the platform (m).
    range_sigma : float
        Gaussian range noise (m).
    min_range, max_range : float
    mixed_pixel_rate : float
        Probability that a slot at a depth discontinuity returns a mixed range.
    dead_angle : tuple(float, float) or None
        Beam-angle interval (rad) of a profiler line that is blocked (backpack, operator).
    platform : str
        ``vehicle`` or ``walking``.
    """

    name: str
    model: SensorModel
    period: float
    mount_height: float
    range_sigma: float
    min_range: float
    max_range: float
    mixed_pixel_rate: float
    dead_angle: tuple[float, float] | None = None
    platform: str = "vehicle"

    def slot_times(self) -> np.ndarray:
        """Firing time of every slot relative to the frame start, ``float64[rows, cols]``."""
        rows, cols = self.model.rows, self.model.cols
        if self.model.continuous_rows:
            line = self.period / rows
            return (np.arange(rows)[:, None] + np.arange(cols)[None, :] / cols) * line
        return np.broadcast_to((np.arange(cols) + 0.5) / cols * self.period, (rows, cols)).copy()

    def line_times(self) -> np.ndarray:
        """Times of the 'lines' poses are stored for: columns (spinning) or rows (profiler)."""
        if self.model.continuous_rows:
            return np.arange(self.model.rows) * self.period / self.model.rows
        return (np.arange(self.model.cols) + 0.5) / self.model.cols * self.period

    def blocked(self) -> np.ndarray:
        """Slots hidden by the dead angle, ``bool[rows, cols]``."""
        mask = np.zeros((self.model.rows, self.model.cols), dtype=bool)
        if self.dead_angle is not None and isinstance(self.model, ProfilerSensor):
            theta = (self.model.angle0 + 2 * np.pi * np.arange(self.model.cols) / self.model.cols) % (2 * np.pi)
            lo, hi = self.dead_angle
            mask[:, (theta > lo) & (theta < hi)] = True
        return mask


def hdl64_altitudes() -> np.ndarray:
    """HDL-64E beam elevations: +2 to -8.33 deg in 1/3 deg, -8.83 to -24.9 deg in ~1/2 deg."""
    return np.radians(np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.9, 32)]))


#: more spinning sensors, as beam layouts of their data sheets' vertical fields of view (uniform beam
#: spacing; images azimuth-aligned, as the readers give Ouster sweeps): name -> (top and bottom beam
#: elevation in deg, beams, columns, mount height, range sigma, min and max range in m)
SPINNING = {
    "hdl32": (10.67, -30.67, 32, 2170, 1.84, 0.02, 1.0, 100.0),  # Velodyne HDL-32E (nuScenes)
    "os1-64": (22.5, -22.5, 64, 1024, 1.9, 0.03, 0.3, 120.0),  # Ouster OS1-64 (rev 6)
    "os0-128": (45.0, -45.0, 128, 1024, 1.9, 0.03, 0.3, 50.0),  # Ouster OS0-128
    "os2-128": (11.25, -11.25, 128, 2048, 1.9, 0.03, 1.0, 200.0),  # Ouster OS2-128
}


def make_sensor(name: str, lines_per_frame: int | None = None, clockwise: bool = False) -> SimSensor:
    """One of :data:`SENSORS`: ``hdl64``, ``vlp16``, ``profiler-urban``, ``profiler-backpack``
    and the beam layouts of :data:`SPINNING`. ``clockwise``: a spinning sensor turns clockwise
    seen from above (azimuth falling with the column, as a Velodyne does), for a packet capture
    whose firing order matches the simulated firing times."""
    spin = -1 if clockwise else 1
    if name == "hdl64":
        return SimSensor(
            name,
            SpinningSensor.create(hdl64_altitudes(), 2048, direction=spin, sweep_period=0.1),
            0.1,
            1.73,
            0.02,
            0.9,
            120.0,
            0.05,
        )
    if name == "vlp16":
        return SimSensor(
            name,
            SpinningSensor.create(np.radians(np.linspace(15, -15, 16)), 1800, direction=spin, sweep_period=0.1),
            0.1,
            1.9,
            0.03,
            0.5,
            100.0,
            0.05,
            platform="walking",
        )
    if name == "profiler-urban":
        rows = lines_per_frame or 99
        rate = 48.0
        # scan plane perpendicular to travel (scanner y-z plane = vehicle y-z), turned 20 deg
        # about z and tilted 10 deg about y, as on the paper's vehicle mount
        mount = _rot("z", 20.0) @ _rot("y", -10.0)
        model = ProfilerSensor.create(rows, 2154, angle0=0.0, line_rate=rate, line_spacing=8.33 / rate, mount=mount)
        return SimSensor(name, model, rows / rate, 2.6, 0.01, 1.0, 120.0, 0.3)
    if name == "profiler-backpack":
        rows = lines_per_frame or 255
        rate = 97.0
        mount = _rot("z", 15.0) @ _rot("y", -20.0)
        model = ProfilerSensor.create(rows, 4270, angle0=0.0, line_rate=rate, line_spacing=1.3 / rate, mount=mount)
        dead = (np.radians(270 - 27.5), np.radians(270 + 27.5))  # 55 deg towards the ground
        return SimSensor(name, model, rows / rate, 2.0, 0.01, 0.5, 80.0, 0.3, dead_angle=dead, platform="walking")
    if name in SPINNING:
        top, bottom, beams, cols, height, sigma, near, far = SPINNING[name]
        model = SpinningSensor.create(
            np.radians(np.linspace(top, bottom, beams)), cols, direction=spin, sweep_period=0.1
        )
        return SimSensor(name, model, 0.1, height, sigma, near, far, 0.05)
    if name in CLOUD_SENSORS:
        raise ValueError(f"{name} gives a point cloud, not a range-image stream: use data_tools.sim.airborne")
    raise ValueError(f"unknown sensor {name!r}; choose from {', '.join(SENSORS)}")


SENSORS = ("hdl64", "vlp16", *SPINNING, "profiler-urban", "profiler-backpack")
#: airborne and terrestrial scanners: unorganised clouds with per-point truth (data_tools.sim.airborne)
CLOUD_SENSORS = ("als", "tls")
