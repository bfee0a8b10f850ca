"""Cross-check of the variants of one ``compare`` run.

Each variant's own health (:class:`~prc_slam.odometry.guard.DivergenceMonitor`) sees a jump, not
a registration that is wrong from its first frame on: a class-aware ICP that stops short of every
16 m step of a 0.5 Hz drive keeps a steady residual and a steady threshold while its trajectory
falls 2.5 m behind per frame. Variants run on the same frames, though, so their motions can be
held against each other: over the last ``agreement_window`` frames, two variants' relative motions
must agree to ``agreement_m`` plus ``agreement_share`` of the path, and to ``agreement_deg`` plus
that share of the angle turned (KITTI's odometry benchmark judges errors in per cent of the path;
good odometry stays near 1 %, so 5 % is a wrong trajectory, not a different choice of points).

When two variants disagree, a yardstick common to both says which is wrong: each frame's points
moved by a variant's frame-to-frame motion into the previous frame, and their distance to the
previous frame's points (mean over the points, each distance capped at one voxel; neither frame
deskewed, the same for every motion), averaged over the window's steps. The variant whose motions
fit clearly worse (by ``agreement_margin``) is flagged suspicious at that frame, with the reason;
when the fits do not tell them apart, both are.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from itertools import combinations, pairwise

import numpy as np

from prc_slam.odometry.group_map import GroupVoxelMap
from prc_slam.odometry.guard import GuardConfig, residuals, rotation_angle

#: points of the current frame taken for the yardstick (evenly spaced in the sensor's order)
_STEP_FIT_POINTS = 8000
#: at most this many points of the previous frame per voxel of its map
_MAP_POINTS_PER_VOXEL = 20


def step_fit(previous: np.ndarray, current: np.ndarray, delta: np.ndarray, voxel: float) -> float:
    """How well the motion ``delta`` (previous sensor frame from current) fits two successive scans:
    the mean distance of ``current``'s points, moved by ``delta``, to the nearest of ``previous``'s
    points in the 27 voxels around them, each distance capped at ``voxel`` (a point without a
    neighbour counts ``voxel``). Lower is better; NaN when either frame has no point.

    Parameters
    ----------
    previous, current : float (N, 3), (M, 3)
        Sensor-frame points of two successive frames (non-finite ones are left out).
    delta : float (4, 4)
        The motion to judge (current frame into the previous one).
    voxel : float
        Voxel of the previous frame's map and cap of each distance (m).
    """
    previous = previous[np.isfinite(previous).all(axis=1)]
    current = current[np.isfinite(current).all(axis=1)]
    if not len(previous) or not len(current):
        return float("nan")
    gmap = GroupVoxelMap(voxel, np.inf, _MAP_POINTS_PER_VOXEL)
    gmap.update(np.asarray(previous, np.float64), np.zeros(len(previous), np.int64), np.eye(4))
    src = np.ascontiguousarray(current[:: max(1, len(current) // _STEP_FIT_POINTS)], dtype=np.float64)
    n_in, mean = residuals(src, np.zeros(len(src), np.int64), *gmap.index(), 1.0 / voxel, voxel**2, delta)
    return float(((mean * n_in if n_in else 0.0) + (len(src) - n_in) * voxel) / len(src))


@dataclass
class Disagreement:
    """Two variants whose motions disagree: where first, how often, by how much, and who is suspect
    (``None``: the yardstick could not tell)."""

    first_frame: int
    frames: int = 0
    max_difference_m: float = 0.0
    max_difference_deg: float = 0.0
    suspects: set[str] = field(default_factory=set)

    def as_dict(self) -> dict:
        return {
            "first_frame": self.first_frame,
            "frames": self.frames,
            "max_difference_m": self.max_difference_m,
            "max_difference_deg": self.max_difference_deg,
            "suspects": sorted(self.suspects),
        }


#: how much wider the agreement bounds are before the guard's warm-up (see :class:`AgreementMonitor`)
EARLY_FACTOR = 3.0


class AgreementMonitor:
    """Holds the running variants' motions against each other, frame by frame (module docstring).

    Parameters
    ----------
    config : GuardConfig
        ``agreement_window``, ``agreement_m``, ``agreement_share``, ``agreement_deg``,
        ``agreement_margin``. Checked from the second frame on, with bounds :data:`EARLY_FACTOR`
        times wider before ``warm_up``: the first frames' motions have no constant-velocity
        prediction behind them, and variants part by a few decimetres before they settle (a
        16-beam walk at 10 Hz: 0.66 m / 4.3 deg between the class-aware and the plain ICP at
        frames 2-10), but a variant lost on a sequence's first steps (keyframes metres apart:
        3.8 m of a 4.3 m step) is flagged there, not after the warm-up.
    voxel : float
        Voxel of the yardstick (:func:`step_fit`), KISS-ICP's.
    """

    def __init__(self, config: GuardConfig, voxel: float) -> None:
        self.config = config
        self.voxel = float(voxel)
        self.pairs: dict[tuple[str, str], Disagreement] = {}
        self._frames: deque[np.ndarray] = deque(maxlen=config.agreement_window + 1)  # the window's points
        self._fits: dict[tuple[str, int], float] = {}  # (variant, frame number) -> fit of its step into it
        self._n = 0  # frames seen

    def _window_fit(self, name: str, poses: list[np.ndarray], w: int) -> float:
        """Mean :func:`step_fit` of ``name``'s last ``w`` steps (each computed once)."""
        fits = []
        for back in range(w):
            key = (name, self._n - 1 - back)
            if key not in self._fits:
                prev, cur = self._frames[-2 - back], self._frames[-1 - back]
                step = np.linalg.inv(poses[-2 - back]) @ poses[-1 - back]
                self._fits[key] = step_fit(prev, cur, step, self.voxel)
            fits.append(self._fits[key])
        return float(np.mean(fits))

    def update(self, index: int, points: np.ndarray, poses: dict[str, list[np.ndarray]]) -> dict[str, str]:
        """Check frame ``index``; ``poses`` are the pose lists of the variants that registered it
        (each ending with this frame's pose). Returns the reason per suspect variant."""
        self._frames.append(points)
        self._n += 1
        c = self.config
        self._fits = {k: v for k, v in self._fits.items() if k[1] > self._n - 2 - c.agreement_window}
        flagged: dict[str, list[str]] = {}
        for a, b in combinations(sorted(poses), 2):
            pa, pb = poses[a], poses[b]
            w = min(c.agreement_window, len(pa) - 1, len(pb) - 1, len(self._frames) - 1)
            if w < 1:
                continue
            ma = np.linalg.inv(pa[-1 - w]) @ pa[-1]
            mb = np.linalg.inv(pb[-1 - w]) @ pb[-1]
            diff_m = float(np.linalg.norm(ma[:3, 3] - mb[:3, 3]))
            diff_deg = float(np.degrees(rotation_angle(ma[:3, :3].T @ mb[:3, :3])))
            path_m, turn_deg = np.maximum(_path(pa[-1 - w :]), _path(pb[-1 - w :]))
            early = EARLY_FACTOR if index < c.warm_up else 1.0
            bound = early * (c.agreement_m + c.agreement_share * path_m)
            bound_deg = early * (c.agreement_deg + c.agreement_share * turn_deg)
            if diff_m <= bound and diff_deg <= bound_deg:
                continue
            d = self.pairs.setdefault((a, b), Disagreement(first_frame=index))
            d.frames += 1
            d.max_difference_m = max(d.max_difference_m, diff_m)
            d.max_difference_deg = max(d.max_difference_deg, diff_deg)
            fa, fb = self._window_fit(a, pa, w), self._window_fit(b, pb, w)
            what = (
                f"disagrees by {diff_m:.2f} m / {diff_deg:.1f} deg over {w} frames (bound {bound:.2f} m / "
                f"{bound_deg:.1f} deg)"
            )
            if np.isfinite(fa) and np.isfinite(fb) and max(fa, fb) > c.agreement_margin * min(fa, fb):
                (worse, fw), (better, fbt) = sorted(((a, fa), (b, fb)), key=lambda x: -x[1])
                d.suspects.add(worse)
                flagged.setdefault(worse, []).append(
                    f"{what} with {better}, whose motions fit successive scans better ({fbt:.3f} vs {fw:.3f} m)"
                )
            else:
                d.suspects.update((a, b))
                for name, other in ((a, b), (b, a)):
                    flagged.setdefault(name, []).append(f"{what} with {other}; successive scans cannot tell which")
        return {name: "; ".join(reasons) for name, reasons in flagged.items()}

    def as_dict(self) -> dict[str, dict]:
        """Per pair ``"a vs b"``: first frame, frames, largest differences, suspects."""
        return {f"{a} vs {b}": d.as_dict() for (a, b), d in self.pairs.items()}


def _path(poses: list[np.ndarray]) -> np.ndarray:
    """Metres travelled and degrees turned along ``poses`` (sums over the steps)."""
    steps = [np.linalg.inv(a) @ b for a, b in pairwise(poses)]
    return np.array(
        [sum(float(np.linalg.norm(s[:3, 3])) for s in steps), sum(np.degrees(rotation_angle(s[:3, :3])) for s in steps)]
    )
