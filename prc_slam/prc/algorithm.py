"""Preregistration classification, Algorithm 1 of Lehtola et al., IEEE TGRS 2019 (paper 000).

Steps (Sec. II):

1. buffer ``k`` scan lines of ``M`` ranges into a block ``B_b`` (Sec. II-A);
2. support ``S_b = B_b \\ F_b`` by eqs. (4)-(8) (Sec. II-B);
3. ``H_b``: background extended by eq. (9) (Sec. II-C), 4-connected components, hole filling
   from the 8-neighbourhood, labels continued from ``R_{b-1}`` with the block boundary vote
   (Sec. II-D);
4. ``V_b``: segments smaller than ``A`` dilated ``gamma`` times and re-segmented (eq. 11,
   Sec. II-E);
5. ``R_b`` combined from ``H_b`` and ``V_b``;
6. classification (Sec. II-F): urban noise / ground / building / vegetation, forest noise /
   ground (eq. 12) / trunk / other vegetation.

All of it runs on the range image alone; the sensor model only enters through the optional
adaptive thresholds (our addition, see :func:`support_thresholds`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from prc_slam import labels as L
from prc_slam.prc import kernels
from prc_slam.prc.config import PRCConfig
from prc_slam.prc.ground import (
    GroundModelError,
    GroundResult,
    GroundState,
    ground_frame,
    ground_from_frame,
    seed_cell_heights,
    seed_in_frame,
)
from prc_slam.scan import Scan, SensorModel, SpinningSensor
from prc_slam.util.threads import ThreadUse, in_threads, side_by_side

log = logging.getLogger("prc_slam.prc")

#: blocks of at least this many slots run their support rows and the column ground's first steps
#: on the numba threads (``NUMBA_NUM_THREADS``; 1: all serial), beside one another
THREADED_SLOTS = 20000

#: |N_adj-slice| of eq. (7): three slots in the previous and three in the next scan line.
N_ADJ = 6


@dataclass
class BlockResult:
    """PRC output for one block.

    Attributes
    ----------
    labels : uint8 (rows, cols)
        Class codes of :mod:`prc_slam.labels`.
    segments : int32 (rows, cols)
        Final segmentation ``R_b`` with stream-wide segment ids (0: noise or no return).
    supported : bool (rows, cols)
        ``S_b`` of eq. (2).
    smooth : bool (rows, cols)
        Points of ``H_b \\ V_b`` (segments of at least ``A`` pixels).
    one_sided : bool (rows, cols)
        Noise points that meet one of the two conditions of eq. (4) (e.g. thin poles).
    row0 : int
        Index of the block's first row in the stream.
    ground : GroundResult, optional
        What the column ground (``config.ground``) found, when it ran.
    ground_error : str, optional
        Why the column ground found no ground in this sweep (no ground below the sensor).
    """

    labels: np.ndarray
    segments: np.ndarray
    supported: np.ndarray
    smooth: np.ndarray
    one_sided: np.ndarray
    row0: int = 0
    ground: GroundResult | None = None
    ground_error: str | None = None


@dataclass
class PRCState:
    """What PRC carries from block ``b-1`` to block ``b`` (continuous streams only)."""

    next_label: int = 1
    last_row: np.ndarray | None = None
    smooth_area: dict[int, int] = field(default_factory=dict)


def support_thresholds(
    ranges: np.ndarray, config: PRCConfig, sensor: SensorModel | None, incidence_deg: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-slot thresholds ``(xi_s, xi_p)``.

    In the paper's mode both are constants. With ``config.adaptive`` (beyond the paper),
    each is raised to the range difference that a surface seen at the incidence angle
    ``beta = adaptive_incidence_deg`` produces between neighbouring slots:
    ``xi(i) = max(xi, tan(beta) * s(i))`` where ``s(i)`` is the slot spacing at normal
    incidence from :meth:`SensorModel.neighbour_spacing` (range times angular step for a
    spinning sensor). Fixed thresholds otherwise cut distant ground on multi-beam sensors,
    where adjacent rings hit the ground metres apart. ``incidence_deg`` overrides ``beta``
    (the one-sided rule's stricter thresholds).
    """
    shape = ranges.shape
    xi_s = np.full(shape, config.xi_s, dtype=np.float32)
    xi_p = np.full(shape, config.xi_p, dtype=np.float32)
    if config.adaptive or incidence_deg is not None:
        if sensor is None:
            raise ValueError("adaptive thresholds (and the one-sided rule) need a sensor model")
        s_in, s_adj = sensor.neighbour_spacing(ranges)
        beta = config.adaptive_incidence_deg if incidence_deg is None else incidence_deg
        factor = np.float32(np.tan(np.radians(beta)))
        np.maximum(xi_s, factor * s_adj, out=xi_s)
        np.maximum(xi_p, factor * s_in, out=xi_p)
    return xi_s, xi_p


def _all_thresholds(
    ranges: np.ndarray, config: PRCConfig, sensor: SensorModel | None, second: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`support_thresholds` and, with ``second``, the one-sided rule's (else the first pair
    again); for a spinning sensor in one pass (:func:`kernels.spinning_thresholds`)."""
    if (
        (config.adaptive or second)
        and isinstance(sensor, SpinningSensor)
        and type(sensor).neighbour_spacing is SpinningSensor.neighbour_spacing
        and ranges.shape == (sensor.rows, sensor.cols)
        and ranges.dtype == np.float32
    ):
        beta2 = config.one_sided_incidence_deg if second else config.adaptive_incidence_deg
        return kernels.spinning_thresholds(
            ranges,
            np.float32(config.xi_s),
            np.float32(config.xi_p),
            sensor.row_step().astype(np.float32),
            np.float32(2.0 * np.pi / sensor.cols),
            np.float32(np.tan(np.radians(config.adaptive_incidence_deg))),
            config.adaptive,
            np.float32(np.tan(np.radians(beta2))),
            second,
        )
    xi_s, xi_p = support_thresholds(ranges, config, sensor)
    if not second:
        return xi_s, xi_p, xi_s, xi_p
    return (xi_s, xi_p, *support_thresholds(ranges, config, sensor, config.one_sided_incidence_deg))


def support_counts_needed(config: PRCConfig) -> tuple[int, int]:
    """Integer forms of eq. (4): ``C_in >= rho_c |N_in-slice|`` and ``C_adj >= rho_c |N_adj-slice|``.

    With the paper's ``rho_c = 1/3`` that is at least 3 of the 8 in-slice neighbours and 2 of
    the 6 adjacent-slice neighbours. (The paper's text quotes the two constants the other way
    round, "= 2" and "≈ 3"; eqs. (4), (7) and (8) give 8/3 and 2, which we follow.)
    """
    need_in = int(np.ceil(config.rho_c * 2 * config.in_slice_half - 1e-9))
    need_adj = int(np.ceil(config.rho_c * N_ADJ - 1e-9))
    return need_in, need_adj


def support_and_background(
    ranges: np.ndarray, config: PRCConfig, sensor: SensorModel | None, wrap: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``S_b`` (eqs. 2-8), ``G_b`` (eq. 9) and the one-sided noise points of a block.

    With ``config.one_sided_incidence_deg`` the one-sided points come from a second pass over
    the unsupported returns under thresholds at that incidence (see
    :func:`kernels.support_and_gradient`)."""
    need_in, need_adj = support_counts_needed(config)
    second = config.one_sided_incidence_deg is not None
    xi_s, xi_p, xi_s2, xi_p2 = _all_thresholds(ranges, config, sensor, second)
    args = (
        config.in_slice_half,
        need_in,
        need_adj,
        config.alpha,
        config.d_c,
        config.gradient == "literal",
        wrap,
        config.gradient_axes == "both",
        not config.adaptive,  # constant thresholds
        config.in_slice_reach,
        xi_s2,
        xi_p2,
        second,
    )
    rows, cols = ranges.shape
    if cols <= 2 * max(config.in_slice_reach, config.in_slice_half) + 1 or not THREADS.use(ranges.size):
        return kernels.support_and_gradient(ranges, xi_s, xi_p, *args)
    # row chunks on the numba threads (plain threads over the serial kernel; same result)
    pr, pt = kernels._padded(ranges, xi_s, wrap)
    out = tuple(np.zeros(ranges.shape, np.bool_) for _ in range(3))

    def work(lo: int, hi: int) -> None:
        kernels.support_rows(ranges, pr, pt, xi_s, xi_p, *args, *out, lo, hi)

    in_threads(THREADS.watched(work), rows, min_chunk=8)
    return out


#: the process-wide :class:`~prc_slam.util.threads.ThreadUse` of :func:`prc_block`: row chunks of the
#: support, and the column ground beside the segmentation (three threaded steps a block); on a free
#: core they save about a third of a KITTI sweep's PRC time
THREADS = ThreadUse(THREADED_SLOTS)


def supported_mask(
    ranges: np.ndarray, config: PRCConfig, sensor: SensorModel | None = None, wrap: bool = False
) -> np.ndarray:
    """``S_b`` of eq. (2): returns that satisfy the support condition (4)."""
    return support_and_background(np.ascontiguousarray(ranges, dtype=np.float32), config, sensor, wrap)[0]


def boundary_relabel(first_row: np.ndarray, prev_row: np.ndarray, min_votes: int) -> dict[int, int]:
    """Block boundary condition of Sec. II-D-2.

    Each point of the last scan line of ``R_{b-1}`` votes for its label to be used by the
    point in the same column of the first line of ``H_b``. A segment of ``H_b`` takes the
    label with the most votes if it has at least ``min_votes``; only nonzero-to-nonzero
    changes are made.

    Parameters
    ----------
    first_row : int array (cols,)
        Segment ids of the first line of ``H_b`` (block-local ids).
    prev_row : int array (cols,)
        Segment ids of the last line of ``R_{b-1}``.

    Returns
    -------
    dict
        Block-local segment id → inherited id.
    """
    m = (first_row > 0) & (prev_row > 0)
    if not m.any():
        return {}
    pairs = np.stack([first_row[m].astype(np.int64), prev_row[m].astype(np.int64)], axis=1)
    uniq, counts = np.unique(pairs, axis=0, return_counts=True)
    keep = counts >= min_votes
    uniq, counts = uniq[keep], counts[keep]
    # for each segment the inherited label with most votes (ties: the smaller label)
    order = np.lexsort((uniq[:, 1], -counts, uniq[:, 0]))
    uniq = uniq[order]
    first = np.ones(len(uniq), dtype=bool)
    first[1:] = uniq[1:, 0] != uniq[:-1, 0]
    return {int(s): int(t) for s, t in uniq[first]}


def prc_block(
    ranges: np.ndarray,
    config: PRCConfig,
    *,
    sensor: SensorModel | None = None,
    wrap: bool = False,
    state: PRCState | None = None,
    row0: int = 0,
    ground_state: GroundState | None = None,
) -> BlockResult:
    """Run Algorithm 1 on one ``k x M`` block.

    Parameters
    ----------
    ranges : float32 (rows, cols)
        Range image of the block, 0 for slots without a return. Not modified.
    config : PRCConfig
    sensor : SensorModel, optional
        Needed only for ``config.adaptive``.
    wrap : bool
        Columns wrap around (spinning sensors).
    state : PRCState, optional
        Carried between consecutive blocks of a continuous stream; updated in place. Without
        it the block stands alone.
    row0 : int
        Stream index of the block's first row (recorded in the result).
    ground_state : GroundState, optional
        Carried between the sweeps of one recording by the column ground (temporal step).
    """
    ranges = np.ascontiguousarray(ranges, dtype=np.float32)
    carry = state is not None
    if not carry and not ranges.any():  # a sweep without a return (said by the pipeline): nothing to do
        none = np.zeros(ranges.shape, bool)
        return BlockResult(
            labels=np.full(ranges.shape, L.NO_RETURN, np.uint8), segments=np.zeros(ranges.shape, np.int32),
            supported=none, smooth=none.copy(), one_sided=none.copy(), row0=row0,
        )  # fmt: skip
    state = state if state is not None else PRCState()
    # Step 2: support, eqs. (4)-(8); step 3b: background extension, eq. (9).
    supported, grad, one_sided = support_and_background(ranges, config, sensor, wrap)

    # Step 6 for spinning sensors: the column ground's first steps need no segments; on large
    # blocks they run beside steps 3-4 (on another numba thread)
    urban = config.mode == "urban"
    columns = _column_ground_applies(config, sensor)

    def segmentation() -> tuple:
        return _segment(ranges, supported, grad, config, wrap, state, carry)

    head: object = None
    if columns:
        assert sensor is not None  # checked by _column_ground_applies
        # ground is a class of the returns that are not isolated: supported or one-sided
        valid = supported | one_sided
        xyz, rays_ranges = _rays_and_ranges(sensor, ranges)
        altitude = getattr(sensor, "altitude", None)

        def ground_head() -> object:
            try:
                frame = ground_frame(xyz, valid, altitude=altitude, state=ground_state, ranges=rays_ranges)
            except GroundModelError as exc:
                return exc
            seeded = seed_in_frame(xyz, valid, config, frame[0], frame[2], frame[3], ranges=rays_ranges)
            return frame, seeded, seed_cell_heights(seeded[0], seeded[1], seeded[2], config)

        if THREADS.use(ranges.size):
            (seg, head), _ = side_by_side(THREADS.watched(segmentation), THREADS.watched(ground_head))
        else:
            seg, head = segmentation(), ground_head()
    else:
        seg = segmentation()
    h_local, glob, uniq, seg_area, smooth, small, dilated, v_local, v_offset, nv = seg

    # Step 5: R_b. Points of small segments, and supported points left unlabelled by hole
    # filling that the dilation reached, take their V_b label; smooth segments keep H_b.
    # Step 6: classification. Urban: the largest smooth patch is ground, other smooth patches
    # building; forest: smooth patches are trunks, ground comes from eq. (12). Spinning sensors
    # (ground "auto" / "columns"): the column ground of prc.ground in either mode.
    ground = 0
    if urban and not columns:
        is_smooth = seg_area >= config.A
        ground = _ground_segment(uniq[is_smooth], seg_area[is_smooth], state if carry else None)

    # (step 5 and step 6's codes in one pass)
    def codes() -> tuple:
        return kernels.combine_codes(
            ranges, h_local, glob.astype(np.int32), smooth, small, dilated, v_local, v_offset, supported, ground,
            L.BUILDING if urban else L.TRUNK, L.GROUND, L.VEGETATION, L.NOISE, L.UNCLASSIFIED,
        )  # fmt: skip

    ground_result, ground_error = None, None
    if columns and not isinstance(head, GroundModelError):
        (plane, tilt, z_ref, order), seeded, height = head

        def ground_tail() -> GroundResult:
            # the column ground's last steps read the ids of smooth segments only, which H_b
            # gives (R_b keeps them): they run beside step 5
            return ground_from_frame(
                xyz, valid, config, plane, tilt, z_ref, order, segments=h_local, smooth=smooth, ranges=rays_ranges,
                n_ids=int(max(glob.max(initial=0), v_offset + nv)) + 1, seeded=seeded, height=height, seg_lut=glob,
            )  # fmt: skip

        if THREADS.use(ranges.size):
            ((segments, _nonsmooth, out), ground_result), _ = side_by_side(
                THREADS.watched(codes), THREADS.watched(ground_tail)
            )
        else:
            (segments, _nonsmooth, out), ground_result = codes(), ground_tail()
        np.copyto(out, np.uint8(L.GROUND), where=ground_result.ground)
    else:
        segments, _nonsmooth, out = codes()
        if columns:
            ground_error = str(head)
            log.debug("PRC column ground: no ground in this sweep: %s", head)
    if not urban and ground_result is None:  # forest: eq. (12), unless the column ground found it
        axis = config.density_axis or ("rows" if wrap else "columns")
        out[column_density_ground(smooth, config, axis) & supported] = L.GROUND

    if carry:
        state.last_row = segments[-1].copy()
    return BlockResult(
        labels=out,
        segments=segments,
        supported=supported,
        smooth=smooth,
        one_sided=one_sided,
        row0=row0,
        ground=ground_result,
        ground_error=ground_error,
    )


def _segment(
    ranges: np.ndarray,
    supported: np.ndarray,
    grad: np.ndarray,
    config: PRCConfig,
    wrap: bool,
    state: PRCState,
    carry: bool,
) -> tuple:
    """Steps 3 and 4 of Algorithm 1 (``H_b`` and ``V_b``); updates ``state``."""
    cols = ranges.shape[1]
    # Step 3: H_b.
    foreground = supported & ~grad
    cc, n = kernels.connected_components(foreground, wrap)
    h_local, local_size = kernels.fill_holes_sized(cc, grad, wrap, n)

    glob = np.arange(n + 1, dtype=np.int64) + (state.next_label - 1)
    glob[0] = 0
    state.next_label += n
    relabel = {}
    if carry and state.last_row is not None and state.last_row.shape == (cols,):
        relabel = boundary_relabel(h_local[0], state.last_row, config.boundary_votes)
        for s, t in relabel.items():
            glob[s] = t

    # Step 4: V_b from the segments smaller than A (eq. 11), sizes counted after relabelling.
    if relabel:
        uniq, inv = np.unique(glob[1:], return_inverse=True)
        seg_area = np.bincount(inv, weights=local_size[1:], minlength=len(uniq))
    else:  # ids 1..n map to distinct, increasing stream ids
        uniq, inv = glob[1:], np.arange(n, dtype=np.intp)
        seg_area = local_size[1:].astype(np.float64)
    smooth_lut = np.zeros(n + 1, dtype=bool)
    smooth_lut[1:] = seg_area[inv] >= config.A
    smooth, small = kernels.split_smooth(h_local, smooth_lut)
    dilated = kernels.dilate4(small, config.gamma, wrap) if config.gamma > 0 else small
    v_local, nv = kernels.connected_components(dilated, wrap)
    v_offset = state.next_label - 1
    state.next_label += nv
    return h_local, glob, uniq, seg_area, smooth, small, dilated, v_local, v_offset, nv


def _rays_and_ranges(sensor: SensorModel, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Arguments ``xyz, ranges`` of :func:`column_ground` for a block: the sensor's unit rays and
    the ranges (the coordinates ``to_xyz`` would give are then computed where needed), or the
    coordinates (and None) from a sensor model with its own ``to_xyz``."""
    if type(sensor).to_xyz is not SensorModel.to_xyz or sensor.unit_rays.shape[:2] != ranges.shape:
        return sensor.to_xyz(ranges), None  # (raises ScanError on a shape mismatch)
    return sensor.unit_rays, ranges


def _column_ground_applies(config: PRCConfig, sensor: SensorModel | None) -> bool:
    """Whether step 6 uses the column ground (:mod:`prc_slam.prc.ground`) for this block.

    ``auto`` uses it for spinning sensors and keeps the paper's rule for profilers (whose
    blocks are what Sec. II-F was made for); ``columns`` insists on a spinning sensor.
    """
    if config.ground == "largest_smooth":
        return False
    spinning = sensor is not None and not sensor.continuous_rows
    if config.ground == "auto":
        return spinning
    if not spinning:
        raise ValueError(
            "PRC ground='columns' needs a spinning sensor's sweep with its sensor model (beams as rows); "
            "use ground='largest_smooth' (the paper's rule) or 'auto' for profilers"
        )
    return True


def _ground_segment(ids: np.ndarray, areas: np.ndarray, state: PRCState | None) -> int:
    """The largest smooth patch, connected over the blocks (Sec. II-F): the smooth segment
    with the largest area accumulated over the consecutive blocks that carried its id.

    Parameters
    ----------
    ids, areas : arrays
        Stream-wide ids of this block's smooth segments and their areas in this block.
    """
    if state is not None:
        areas = areas + np.array([state.smooth_area.get(int(u), 0) for u in ids], dtype=np.int64)
        state.smooth_area = {int(u): int(a) for u, a in zip(ids, areas, strict=True)}
    if len(ids) == 0:
        return 0
    return int(ids[np.argmax(areas)])


def column_density_ground(smooth: np.ndarray, config: PRCConfig, axis: str = "columns") -> np.ndarray:
    """Forest ground by the column smoothness density of eq. (12).

    ``rho = (1/k) sum_j [p_j in H_b \\ V_b]`` is evaluated on every ``density_stride``-th
    column starting at column 0; a column with ``rho > density_threshold`` and the
    ``density_stride - 1`` columns after it are declared ground. A profiler's block column is
    one scan angle over ``k`` successive lines; with ``axis="rows"`` (beyond the paper, for
    spinning sensors) the same density is taken along one beam's ring over windows of
    ``density_window`` columns, the spinning sensor's "fixed scan angle over successive
    firings".

    Returns
    -------
    bool (rows, cols)
        True in the ground columns (or ring windows).
    """
    rows, cols = smooth.shape
    if axis == "rows":
        w = config.density_window
        n_win = -(-cols // w)
        padded = np.zeros((rows, n_win * w), dtype=bool)
        padded[:, :cols] = smooth
        rho = padded.reshape(rows, n_win, w).sum(axis=2) / np.minimum(w, cols - np.arange(n_win) * w)[None, :]
        return np.repeat(rho > config.density_threshold, w, axis=1)[:, :cols]
    stride = config.density_stride
    rho = smooth[:, ::stride].sum(axis=0) / rows
    is_ground = np.repeat(rho > config.density_threshold, stride)[:cols]
    return np.broadcast_to(is_ground[None, :], smooth.shape)


class PRCStream:
    """Streaming PRC: accepts scan lines in chunks of any size and labels complete blocks.

    Lines are buffered into blocks of ``config.k`` lines (Algorithm 1, step 1); labels do not
    depend on how the stream is chunked. Continuous sensors (profilers) carry segment ids
    over block boundaries; for other sensors every block stands alone, except that the column
    ground (:mod:`prc_slam.prc.ground`) carries its ground plane from sweep to sweep.

    Parameters
    ----------
    config : PRCConfig
    sensor : SensorModel
        Supplies ``cols`` (= M), ``continuous_rows``, and the spacing for adaptive thresholds.
    """

    def __init__(self, config: PRCConfig, sensor: SensorModel) -> None:
        self.config = config
        self.sensor = sensor
        self.wrap = (not sensor.continuous_rows) if config.wrap_columns is None else config.wrap_columns
        self.state = PRCState()
        self.ground_state = GroundState()
        self._buffer: list[np.ndarray] = []
        self._buffered = 0
        self._rows_done = 0

    def push(self, lines: np.ndarray) -> list[BlockResult]:
        """Add scan lines ``float32[n, M]`` (a single line may be 1-D); return finished blocks."""
        lines = np.asarray(lines, dtype=np.float32)
        if lines.ndim == 1:
            lines = lines[None, :]
        if lines.ndim != 2 or lines.shape[1] != self.sensor.cols:
            raise ValueError(f"scan lines must have shape (n, {self.sensor.cols}), got {lines.shape}")
        lines = np.where(np.isnan(lines), np.float32(0), lines)
        if np.isinf(lines).any() or (lines < 0).any():
            raise ValueError("scan lines contain infinite or negative ranges")
        out: list[BlockResult] = []
        k = self.config.k
        start = 0
        while start < len(lines):
            take = min(k - self._buffered, len(lines) - start)
            self._buffer.append(lines[start : start + take])
            self._buffered += take
            start += take
            if self._buffered == k:
                out.append(self._run_block())
        return out

    def flush(self) -> list[BlockResult]:
        """Label the incomplete last block, if any."""
        return [self._run_block()] if self._buffered else []

    def _run_block(self) -> BlockResult:
        block = np.concatenate(self._buffer, axis=0)
        self._buffer, self._buffered = [], 0
        carry = self.state if self.sensor.continuous_rows else None
        res = prc_block(
            block,
            self.config,
            sensor=self.sensor,
            wrap=self.wrap,
            state=carry,
            row0=self._rows_done,
            ground_state=None if self.sensor.continuous_rows else self.ground_state,
        )
        self._rows_done += len(block)
        return res


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel, so that timings measure the work."""
    tiny = np.ones((4, 12), dtype=np.float32)
    for mode in ("urban", "forest"):
        config = PRCConfig(mode=mode, k=2)
        prc_block(tiny, config, wrap=True, state=PRCState())
        prc_block(tiny, config.model_copy(update={"adaptive": True}), sensor=_WarmSensor(), wrap=False)
    # a spinning sweep over flat ground with a wall: the column ground's kernels too, and (as
    # large as THREADED_SLOTS) the threaded steps' kernels
    cols = -(-THREADED_SLOTS // 32)
    sensor = SpinningSensor.create(np.radians(np.linspace(2.0, -24.0, 32)), cols)
    down = np.maximum(-np.sin(sensor.altitude), 1e-3)[:, None]
    ranges = np.minimum(1.7 / down, 12.0) * np.ones((1, cols))
    prc_block(ranges.astype(np.float32), PRCConfig.preset("multibeam"), sensor=sensor, wrap=True,
              ground_state=GroundState())  # fmt: skip


class _WarmSensor(SensorModel):
    """Minimal sensor for :func:`warm_up` (unit spacing everywhere)."""

    def __init__(self) -> None:
        super().__init__(rows=4, cols=12, continuous_rows=False)

    def neighbour_spacing(self, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        one = np.ones_like(ranges, dtype=np.float32)
        return one, one


def classify_scan(scan: Scan, config: PRCConfig) -> np.ndarray:
    """PRC labels for one scan on its own, ``uint8[rows, cols]``.

    A spinning sensor's sweep is one block. A profiler scan's lines are cut into blocks of
    ``config.k`` (the last one shorter); for a recording split into several scans use
    :func:`prc_slam.pipeline.classify_frames`, which keeps one stream across them.
    """
    if not scan.sensor.continuous_rows:
        wrap = True if config.wrap_columns is None else config.wrap_columns
        return prc_block(scan.ranges, config, sensor=scan.sensor, wrap=wrap).labels
    stream = PRCStream(config, scan.sensor)
    results = stream.push(scan.ranges) + stream.flush()
    return np.concatenate([r.labels for r in results], axis=0)
