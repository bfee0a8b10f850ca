"""The car and curb algorithms of Stamos et al. (paper 001) carried to spinning multi-beam sensors.

A 64-beam column holds a handful of returns per car side, too few for the per-column H/V/M
chains and dividers of Sec. 7.2-7.3; a ring, on the other hand, is a dense horizontal profile
of everything at one elevation. Still online (one sweep at a time, nothing learned). The steps,
and the paper section each follows or where it departs:

1. Local ground along the column profile (Sec. 5): the ground algorithm runs on the columns as
   before (:class:`~prc_slam.online.ground.GroundDetector`); each return's ground height is that
   of the last ground return below it in its own column (:func:`local_ground`), else the column's
   ``z_i`` / the dominant ``z_d``. Columns too short for part (a)'s 10 horizontal returns (a
   16-beam sensor) take :func:`column_ground`: part (b) with one ``z_i`` per column.
2. Candidates (Sec. 3, contextual truth 1 and 3): non-ground returns between
   ``min_above_ground`` (above the tallest curb, ``t_curb = 0.2 m`` of Sec. 6) and ``max_height``
   above the local ground.
3. Intervals along rings and across beams (Sec. 7.3, dividers): a candidate joins the next return
   along its ring and up its column (missing slots, the M state of windows and dark paint, are
   skipped while the skipped span stays under ``max_gate``; up a column a farther return, seen
   through a window, counts as missing, ``see_through``) unless the step between them is a
   divider, longer than ``max(min_gate, gate_factor x`` the expected slot spacing at that range
   ``)``: the spinning analogue of ``t_sep``, scaled to the beam pattern. Along a ring a farther
   return is the background and always divides. Connected candidates form segments.
4. High verticals (Sec. 7.4): a segment whose returns go on upward past ``max_height`` in the next
   beam of the same column, or reach the highest beam (the object may go on out of view), on more
   than ``high_share`` of its column tops at least ``top_floor`` above the ground (its upper
   outline: a car's roof, a trunk going on up; the low tops of a shrub at a trunk's foot no longer
   dilute the share), is a wall, a tree or a pole ("no car can lie behind such vertical objects"
   becomes: no car is part of one). ``top_floor`` 1.0 m instead of 0: simulated hdl64 forest,
   20 sweeps, seeds 0 / 1, 0.081 / 0.119 % -> 0.020 / 0.036 % of the points called vehicle,
   vlp16 forest 0.34 -> 0.08 %; KITTI P 0.858 -> 0.874, recall and cars found unchanged.
5. Contextual truth 3 (Sec. 3): a car's top lies at least ``min_top`` above the ground (less the
   beam gap above its highest return, at most ``max_top_gap``; across beams above it that returned
   nothing though they would meet the ground within the sweep's range, ``missing_top``), 90 % of its returns lie at most
   ``max_top`` above it, its lowest return within ``max_bottom`` of it (cars stand on the
   ground; less the slot spacing below each return, range x the gap to the next beam down, which
   missed the object: ``bottom_gap``), its footprint (the least-area rectangle over 18 headings,
   ``min_area``; a car seen at a corner, with some returns of its far side, spreads alike both
   ways and its principal-axis extent was up to 3.9 m wide: simulated hdl64 seed 2, 74 -> 80 of
   111 vehicles found) between
   ``min_length`` and ``max_length`` long and at most ``max_width`` wide, and it is no thin sheet
   (``min_thickness``, the 10-90 % spread across its principal axis).
5b. Grazing surfaces: a beam meets a roof or a bonnet at a grazing angle, metres beyond the car's
   face below it (the rear window between them returns nothing), farther than any divider allows;
   the face alone is too low for a car, the roof too small. A face (a segment standing on the
   ground but too low for a car) and the segments above it, linked on at least ``grazing_links``
   columns where the face ends in a vertical step (steeper than 45 deg) and the next return up
   is the other one's, farther out by at most ``max_length`` (:func:`grazing_links`), are judged
   together by steps 4-6; when the whole passes, it is one car, otherwise every part keeps its
   own verdict (no chains, no roof shared by two faces). Rising terrain has no vertical face and
   links nothing; a thin sign or wall is no face (tall enough already: on KITTI frame 9 its
   merge with two returns 3.7 m behind it passed the thin-sheet test). Simulated hdl64 seed 1
   (a car 42 m ahead, seen from behind in all 20 sweeps): 40 -> 57 of 68 vehicles found; seed 0
   63 -> 72 of 80; KITTI 0-2 and the forests unchanged.
6. Car vs vegetation (Sec. 7.1 / 7.5): vegetation makes the signed angles of a profile alternate;
   along a ring that is a large normalised second difference ``|X_a - 2 X_b + X_c| / |X_c - X_a|``
   between successive returns at least ``ring_baseline`` apart (closer ones differ by their range
   noise). A segment whose median exceeds ``max_roughness``, which shows fewer than
   ``min_ring_triples`` such triples (no run along a ring: a bush or a trunk seen edge on), or of
   which the coarse classifier (Sec. 4) calls more than ``max_vegetation`` vegetation, is no car
   (its calls judged again over the baseline the sweep's range noise asks for where that noise turns
   its successive steps by ``vegetation_regime`` or more: :mod:`prc_slam.online.noise`).
   (The Fourier test needs longer runs than the 5-30 returns a ring gives per car at range.)

7. Car returns down to the ground (Sec. 7, the paper's cars start at the ground): below each
   accepted segment the next returns down each column join it while they lie more than ``down_to``
   above the local ground and within ``min_gate`` of the return above (:func:`grow_down`; KITTI
   recall 0.71 -> 0.77, precision 0.87 -> 0.86).

Each accepted segment is one car instance with an oriented box (principal axis of its footprint).
Curbs: :func:`detect_curbs_spinning` (Sec. 6 with the column's own steps as "vertical").
Measured (``OnlineDetector()``, vehicles per point; found = >= 50 % of an instance's points):
KITTI 00 frames 0-2 (car, truck, other-vehicle) P 0.873 / R 0.775, 22 of 36 cars; simulated
hdl64 urban, 20 sweeps: seed 0 P 0.999 / R 0.964, 72 of 80, seed 1 P 0.999 / R 0.953, 57 of 68,
seed 2 P 1.000 / R 0.953, 80 of 111; vlp16 seed 0 P 0.948 / R 0.806, 36 of 60, seed 1 P 0.938 /
R 0.753, 25 of 39; forest (20 sweeps) hdl64 seeds 0 / 1 0.020 / 0.036 %, vlp16 0.084 % of the
points called vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from prc_slam.online.car import oriented_boxes_of
from prc_slam.online.coarse import elevation_rows
from prc_slam.online.kernels import relabel
from prc_slam.scan import Scan, SpinningSensor
from prc_slam.util import unionfind as uf
from prc_slam.util.threads import in_threads


@dataclass(frozen=True)
class SpinningCarParams:
    """Car geometry and segment links for spinning sensors (module docstring, steps 2-6).

    Measured while choosing them (KITTI 00 frames 0-2, vehicle P / cars found of 36; simulated
    hdl64 forest, share of points called vehicle): ``max_top`` 2.3 on 90 % of the returns instead
    of no limit, P 0.79 -> 0.87 (trees with low branches, structures), found 23 -> 22;
    ``min_ring_triples`` 3 instead of 0, forest 0.15 % -> 0.02 %; ``see_through`` off, P 0.81,
    found 22, but a simulated car at 4 m (5,000 returns, its windows showing the far side) splits
    in three; ``diagonal`` on, found 23, forest 0.11 %; ``ring_baseline`` 0.2 -> 0.3 m with
    ``max_roughness`` 0.35, found 21 -> 25 (the roughness of 0.2 m triples is mostly range noise
    at 25 m). The KITTI reader changed while these were measured; the figures compare like with like.
    """

    min_above_ground: float = 0.25  # m, above Sec. 6's tallest curb (t_curb = 0.2 m)
    max_height: float = 2.6  # m above ground: candidates, and the high-vertical limit
    min_gate: float = 0.5  # m
    gate_factor: float = 3.0  # times the expected slot spacing at that range
    max_gate: float = 2.0  # m
    see_through: bool = True  # up a column, a farther return (through a window) counts as missing
    diagonal: bool = False  # also link up the neighbouring columns (staggered or grazing returns)
    ring_baseline: float = 0.3  # m, least step between the returns of a ring triple (step 6)
    min_points: int = 12
    min_top: float = 1.15  # m above ground: a car roof (1.4-1.6 m) less the local ground's error
    max_top: float = 2.3  # m above ground, 90 % of a segment's returns: cars, SUVs, most vans
    max_top_gap: float = 0.6  # m, most of the beam gap above a segment the roof test allows
    min_length: float = 1.0  # m: the longer footprint side; a car's shortest side is ~1.6 m
    max_bottom: float = 0.5  # m above ground
    max_length: float = 8.0  # m
    max_width: float = 3.2  # m
    min_thickness: float = 0.15  # m, 10-90 % spread across the principal axis
    high_share: float = 0.2
    max_roughness: float = 0.35
    min_ring_triples: int = 3  # ring triples (returns >= ring_baseline apart along a ring) a car shows at least
    down_to: float = 0.05  # m: accepted cars grow down their columns to this height (0: off)
    max_vegetation: float = 0.5  # share of the segment's returns the coarse classifier calls vegetation
    min_area: bool = True  # footprint as the least-area rectangle (False: along the principal axis)
    top_floor: float = 1.0  # m above ground: lower column tops do not count in high_share (0: all count; step 4)
    grazing_links: int = 2  # columns linking two segments across a grazing surface (step 5b; 0: off)
    # m, baseline of the signed angles behind step 6's vegetation share on sensors whose median beam gap is
    # under vegetation_gap (deg; finer than an HDL-64's 1/3 deg): at an OS2-128's 0.18 deg a car face's
    # returns lie 3 cm apart at 10 m, its range noise, and cars were called vegetation (0: Sec. 4's).
    # On KITTI's HDL-64 the baseline would smooth hedges into cars (vehicle P 0.87 -> 0.77)
    vegetation_step: float = 0.1
    vegetation_gap: float = 0.25
    # step 6's vegetation share, on every spinning sensor, from signed angles taken over the baseline the sweep's own
    # range noise asks for (prc_slam.online.noise: sqrt(2) sigma / tan(veg_sigma), 0.117 m at 3 cm) where the column
    # spacing is under it, the paper's successive steps elsewhere (False: vegetation_step on gaps under vegetation_gap)
    vegetation_noise: bool = True
    # deg: ... where the noise turns the paper's successive steps by this much or more (noise_baseline(sigma, angle)
    # over the column spacing): 30 deg reaches 24 m on an OS2-128 (3 cm of noise), 5.9 m on an OS0-128 / OS1-64, 7 m on
    # a 2 cm HDL-64, 4.6 m on KITTI (1.1 cm). Chosen on street seeds 0-2 between the classifier's state spread (20:
    # two OS1-64 cars at 8 m lost, the centred steps spreading the window band's see-through returns over twice the
    # steps) and halfway between two states (45: an OS2-128 car at 10-20 m lost); both give os0-128 0-10 m 70 of 73
    vegetation_regime: float = 30.0
    vegetation_regime: float = 30.0
    hidden_floor: bool = True  # step 5's bottom taken above where the lowest beam passes (False: above the ground)
    # m: step 4's column tops on the highest beam lower than top_height above the ground count as going on upward
    # only for a segment whose tops there span less than top_width along the ring (0: always): near a sensor whose
    # highest beam points little above the horizon (HDL-64: +2 deg) the field of view ends on a van's side (5 m
    # out: 2.0 m up), which says nothing of what lies above; a trunk or a pole cut there spans less, and a facade
    # cut above max_top is taller than any vehicle the detector takes
    top_width: float = 1.0
    top_height: float = 2.3
    # m: step 6's vegetation share counts only returns whose beams lie closer than this there (range x beam gap),
    # over at least min_points of them (else the share is not tested); 0: every return (the share before)
    veg_resolution: float = 0.2
    # step 4: a high return above a column top counts only when it continues the face upwards (steeper than
    # 45 deg), not a street tree's crown over a parked van (False: any high return within the gate)
    high_steep: bool = True
    # step 5: a segment's bottom measured less the slot spacing up its column below each return (range x the gap
    # to the next beam down), where the object may go on unseen (False: from the return itself)
    bottom_gap: bool = True
    # step 5: the roof test's allowance above a segment's highest return reaches up to the next beam with a return
    # across beams that returned nothing though they point at the ground within the sweep's range (glass, dark
    # paint: a car's window band seen from beside it), capped at max_top_gap (False: the next beam's gap)
    missing_top: bool = True


@njit(cache=True, nogil=True)
def graph_components(n_nodes, a, b):
    """Connected components of the undirected graph on nodes ``0..n_nodes - 1`` with edges
    ``a[i] - b[i]``: a label per node, numbered 0, 1, ... in the order of each component's lowest
    node (as ``scipy.sparse.csgraph.connected_components`` numbers them)."""
    parent = np.arange(n_nodes)
    for i in range(a.shape[0]):
        uf.union(parent, a[i], b[i])
    return uf.component_ids(parent)


@njit(cache=True, nogil=True)
def _d2(xyz, r0, c0, r1, c1):
    dx = xyz[r0, c0, 0] - xyz[r1, c1, 0]
    dy = xyz[r0, c0, 1] - xyz[r1, c1, 1]
    dz = xyz[r0, c0, 2] - xyz[r1, c1, 2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True)
def segment_candidates(
    cand, valid, high, xyz, rng, ring_step, alt, min_gate, gate_factor, max_gate, see_through, diagonal,
    height, top_floor, top_width=0.0, steep=False, top_height=-np.inf,
):  # fmt: skip
    """Steps 3-4 on an image whose rows are beams in elevation order (lowest first).

    Returns ``(seg, n, high_touch, tops)``: segment id per slot (0 = none), the number of
    segments, and per segment the number of its column tops whose next return up is ``high``
    and within the gate, and the number of its column tops; only tops at least ``top_floor``
    above the ground (``height``) count, the segment's upper outline, where a car has its roof
    and a trunk goes on up (a shrub at its foot adds low tops that would dilute the share)."""
    R, C = cand.shape
    parent = np.arange(R * C + 1)  # int64 (numba's arange of an int64 count); no copy by astype
    for r in range(R):
        for c in range(C):
            if not cand[r, c]:
                continue
            # next return along the ring (wrapping), skipping missing slots over at most max_gate
            for s in range(1, C):
                if s > 1 and rng[r, c] * ring_step * (s - 1) > max_gate:
                    break
                c1 = (c + s) % C
                if not valid[r, c1]:  # missing (M); a farther return is the background: a divider
                    continue
                if cand[r, c1]:
                    g = max(min_gate, min(max_gate, gate_factor * rng[r, c] * ring_step * s))
                    if _d2(xyz, r, c, r, c1) <= g * g:
                        uf.union(parent, r * C + c + 1, r * C + c1 + 1)
                break
            # next return up the column, and up its two neighbouring columns
            for dc in range(-diagonal, diagonal + 1):
                c2 = (c + dc) % C
                for s in range(1, R):
                    r1 = r + s
                    if r1 >= R or (s > 1 and rng[r, c] * (alt[r1 - 1] - alt[r]) > max_gate):
                        break
                    if not valid[r1, c2] or (see_through and rng[r1, c2] > rng[r, c] + max_gate):  # M, or glass
                        continue
                    if cand[r1, c2]:
                        g = max(min_gate, min(max_gate, gate_factor * rng[r, c] * (alt[r1] - alt[r])))
                        if _d2(xyz, r, c, r1, c2) <= g * g:
                            uf.union(parent, r * C + c + 1, r1 * C + c2 + 1)
                    break
    seg = np.zeros((R, C), np.int32)
    root_id = np.zeros(R * C + 1, np.int32)
    n = 0
    for r in range(R):
        for c in range(C):
            if cand[r, c]:
                root = uf.find(parent, r * C + c + 1)
                if root_id[root] == 0:
                    n += 1
                    root_id[root] = n
                seg[r, c] = root_id[root]
    high_touch, tops = outline_tops(
        seg, n, valid, high, xyz, rng, alt, min_gate, gate_factor, max_gate, height, top_floor, top_width, steep,
        top_height,
    )  # fmt: skip
    return seg, n, high_touch, tops


@njit(cache=True, nogil=True)
def row_spans(seg):
    """Per row of ``seg`` (rows, cols): the first column holding a non-zero id and one past the last
    (``(0, 0)`` for a row without any). The per-segment passes below visit only these spans: they skip
    id 0, and a ring's run state starts afresh at the first id of a row either way, so the results are
    those of a pass over every slot, at a fraction of the cost on a sparse image (the step 5b groups)."""
    R, C = seg.shape
    lo = np.zeros(R, np.int64)
    hi = np.zeros(R, np.int64)
    for r in range(R):
        first = -1
        last = -1
        for c in range(C):
            if seg[r, c] != 0:
                if first < 0:
                    first = c
                last = c
        if first >= 0:
            lo[r] = first
            hi[r] = last + 1
    return lo, hi


#: m, range noise allowed in step 4's steepness test (``high_steep``)
STEEP_SLACK = 0.1


@njit(cache=True, nogil=True)
def outline_tops(
    seg, n, valid, high, xyz, rng, alt, min_gate, gate_factor, max_gate, height, top_floor,
    top_width=0.0, steep=False, top_height=-np.inf,
):  # fmt: skip
    """Step 4 per segment 1..n of ``seg`` (rows in elevation order): the number of its column
    tops at least ``top_floor`` above the ground whose next return up is ``high`` and within the
    gate (or which lie on the highest beam), and the number of those column tops. A top on the
    highest beam under ``top_height`` above the ground counts only for a segment whose tops there
    span less than ``top_width`` along the ring (``top_width`` > 0: a trunk or a pole going on out
    of view; a vehicle cut by the field of view under a tall vehicle's height spans more). With
    ``steep``, a high return counts only where it continues the face
    upwards (it lies no farther out, horizontally, than it lies higher, give or take
    :data:`STEEP_SLACK` of range noise: steeper than 45 deg), not a crown or an awning reaching
    over the object."""
    R, C = seg.shape
    high_touch = np.zeros(n + 1, np.int64)
    tops = np.zeros(n + 1, np.int64)
    at_top = np.zeros(n + 1, np.int64)  # tops on the highest beam, their column span and mean range
    c_lo = np.full(n + 1, C, np.int64)
    c_hi = np.full(n + 1, -1, np.int64)
    r_sum = np.zeros(n + 1)
    span_lo, span_hi = row_spans(seg)
    for r in range(R):  # image order in memory (each column is read upwards from every slot)
        for c in range(span_lo[r], span_hi[r]):
            k = seg[r, c]
            if k == 0:
                continue
            # the next return up this column
            up = -1
            for r1 in range(r + 1, R):
                if valid[r1, c]:
                    up = r1
                    break
            if up >= 0 and seg[up, c] == k:
                continue
            if height[r, c] < top_floor:
                continue
            tops[k] += 1
            if up < 0 and r == R - 1:  # on the highest beam: the object may go on out of view
                if height[r, c] >= top_height or top_width <= 0.0:
                    high_touch[k] += 1
                    continue
                at_top[k] += 1
                c_lo[k] = min(c_lo[k], c)
                c_hi[k] = max(c_hi[k], c)
                r_sum[k] += rng[r, c]
            elif up >= 0 and high[up, c]:
                g = max(min_gate, min(max_gate, gate_factor * rng[r, c] * (alt[up] - alt[r])))
                if _d2(xyz, r, c, up, c) <= g * g:
                    if steep:
                        rho0 = np.sqrt(xyz[r, c, 0] ** 2 + xyz[r, c, 1] ** 2)
                        rho1 = np.sqrt(xyz[up, c, 0] ** 2 + xyz[up, c, 1] ** 2)
                        if abs(rho1 - rho0) > xyz[up, c, 2] - xyz[r, c, 2] + STEEP_SLACK:
                            continue
                    high_touch[k] += 1
    for k in range(1, n + 1):
        if at_top[k] == 0:
            continue
        span = (r_sum[k] / at_top[k]) * (2.0 * np.pi / C) * (c_hi[k] - c_lo[k] + 1)
        if span < top_width:
            high_touch[k] += at_top[k]
    return high_touch, tops


@njit(cache=True, nogil=True)
def segment_features(
    seg, n, xyz, height, valid, baseline, min_area=True, area_points=0, area_top=np.inf, area_bottom=np.inf,
    floor=None,
):  # fmt: skip
    """Per segment (index 1..n): points, lowest and highest height above ground, footprint
    length / width (of the least-area rectangle over 18 headings; ``min_area=False``: along the
    principal axis), thickness (10-90 % spread across that
    axis, from a histogram), and the median normalised second difference along rings.

    The least-area rectangle is searched only for segments of at least ``area_points`` returns
    whose 90 % height is at most ``area_top`` and whose lowest return at most ``area_bottom``
    (what a car must pass anyway; buildings and trees, most of the returns, fail it): the others
    keep the extents along the principal axis.

    ``floor`` (rows, cols; optional): per slot, how high above the ground the sensor's lowest beam
    passes at that slot's distance; the lowest height is then taken above it (what the sensor
    cannot see below a return does not count against the segment's bottom, step 5)."""
    R = seg.shape[0]
    span_lo, span_hi = row_spans(seg)  # the columns of each row that hold a segment
    cnt = np.zeros(n + 1)
    sx = np.zeros(n + 1)
    sy = np.zeros(n + 1)
    sxx = np.zeros(n + 1)
    sxy = np.zeros(n + 1)
    syy = np.zeros(n + 1)
    hlo = np.full(n + 1, np.inf)
    hhi = np.full(n + 1, -np.inf)
    nh = 64
    hh = np.zeros((n + 1, nh), np.int32)  # heights in 0.1 m bins (int32: a quarter of the memory)
    for r in range(R):
        for c in range(span_lo[r], span_hi[r]):
            k = seg[r, c]
            if k == 0:
                continue
            x = xyz[r, c, 0]
            y = xyz[r, c, 1]
            cnt[k] += 1
            sx[k] += x
            sy[k] += y
            sxx[k] += x * x
            sxy[k] += x * y
            syy[k] += y * y
            if floor is None:
                hlo[k] = min(hlo[k], height[r, c])
            else:
                hlo[k] = min(hlo[k], height[r, c] - floor[r, c])
            hhi[k] = max(hhi[k], height[r, c])
            hh[k, min(nh - 1, max(0, int(height[r, c] / 0.1)))] += 1
    mx = sx / np.maximum(cnt, 1)
    my = sy / np.maximum(cnt, 1)
    ux = np.ones(n + 1)
    uy = np.zeros(n + 1)
    for k in range(1, n + 1):
        a = sxx[k] / max(cnt[k], 1) - mx[k] ** 2
        b = sxy[k] / max(cnt[k], 1) - mx[k] * my[k]
        d = syy[k] / max(cnt[k], 1) - my[k] ** 2
        theta = 0.5 * np.arctan2(2 * b, a - d)  # principal axis of the 2x2 covariance
        ux[k] = np.cos(theta)
        uy[k] = np.sin(theta)
    lo_u = np.full(n + 1, np.inf)
    hi_u = np.full(n + 1, -np.inf)
    lo_v = np.full(n + 1, np.inf)
    hi_v = np.full(n + 1, -np.inf)
    nb = 64
    hist = np.zeros((n + 1, nb), np.int32)
    bin_w = 0.1  # m, histogram of the across-axis offset over +-3.2 m
    for r in range(R):
        for c in range(span_lo[r], span_hi[r]):
            k = seg[r, c]
            if k == 0:
                continue
            x = xyz[r, c, 0] - mx[k]
            y = xyz[r, c, 1] - my[k]
            u = x * ux[k] + y * uy[k]
            v = -x * uy[k] + y * ux[k]
            lo_u[k] = min(lo_u[k], u)
            hi_u[k] = max(hi_u[k], u)
            lo_v[k] = min(lo_v[k], v)
            hi_v[k] = max(hi_v[k], v)
            b = int(np.floor(v / bin_w)) + nb // 2
            hist[k, min(nb - 1, max(0, b))] += 1
    thick = np.zeros(n + 1)
    for k in range(1, n + 1):
        lo_q = 0.1 * cnt[k]
        hi_q = 0.9 * cnt[k]
        acc = 0.0
        b10 = -1
        b90 = -1
        for b in range(nb):
            acc += hist[k, b]
            if b10 < 0 and acc >= lo_q:
                b10 = b
            if b90 < 0 and acc >= hi_q:
                b90 = b
        thick[k] = (b90 - b10) * bin_w
    # roughness along rings: normalised second differences of returns of one segment taken at
    # least ``baseline`` apart along the ring (closer returns differ by their range noise)
    rough_hist = np.zeros((n + 1, 20), np.int32)
    n_rough = np.zeros(n + 1, np.int64)
    for r in range(R):
        k0 = 0
        p1 = -1
        p2 = -1
        for c in range(span_lo[r], span_hi[r]):
            if not valid[r, c]:
                continue
            k = seg[r, c]
            if k != k0:  # another segment or none: start again
                k0 = k
                p1 = c if k != 0 else -1
                p2 = -1
                continue
            if k == 0:
                continue
            d2 = _d2(xyz, r, c, r, p1)
            if d2 < baseline * baseline:
                continue
            if p2 >= 0:
                ax = xyz[r, p2, 0] - 2 * xyz[r, p1, 0] + xyz[r, c, 0]
                ay = xyz[r, p2, 1] - 2 * xyz[r, p1, 1] + xyz[r, c, 1]
                az = xyz[r, p2, 2] - 2 * xyz[r, p1, 2] + xyz[r, c, 2]
                q = np.sqrt(ax * ax + ay * ay + az * az) / max(np.sqrt(_d2(xyz, r, c, r, p2)), 1e-6)
                rough_hist[k, min(19, int(q * 10.0))] += 1
                n_rough[k] += 1
            p2 = p1
            p1 = c
    rough = np.zeros(n + 1)
    for k in range(1, n + 1):
        if n_rough[k] == 0:
            rough[k] = 0.0
            continue
        acc = 0.0
        for b in range(20):
            acc += rough_hist[k, b]
            if acc >= 0.5 * n_rough[k]:
                rough[k] = (b + 0.5) / 10.0
                break
    top90 = np.zeros(n + 1)
    for k in range(1, n + 1):
        acc = 0.0
        for b in range(nh):
            acc += hh[k, b]
            if acc >= 0.9 * cnt[k]:
                top90[k] = (b + 1) / 10.0  # the bin's upper edge, correctly rounded (2.3, not 2.3000000000000003)
                break
    length = np.maximum(hi_u - lo_u, 0.0)
    width = np.maximum(hi_v - lo_v, 0.0)
    if min_area:
        # the footprint as the least-area rectangle over n_ang headings (5 deg apart): a car seen
        # at a corner shows an L, whose principal axis runs along the diagonal and whose extent
        # across it is wider than the car
        n_ang = 18
        ca = np.cos(np.arange(n_ang) * (0.5 * np.pi / n_ang))
        sa = np.sin(np.arange(n_ang) * (0.5 * np.pi / n_ang))
        area = (cnt >= area_points) & (top90 <= area_top) & (hlo <= area_bottom)
        at = np.full(n + 1, -1, np.int64)  # row of each searched segment in lo_a / hi_a
        na = 0
        for k in range(1, n + 1):
            if area[k]:
                at[k] = na
                na += 1
        lo_a = np.full((na, n_ang, 2), np.inf)
        hi_a = np.full((na, n_ang, 2), -np.inf)
        for r in range(R):
            for c in range(span_lo[r], span_hi[r]):
                k = seg[r, c]
                if k == 0 or not area[k]:
                    continue
                i = at[k]
                x = xyz[r, c, 0] - mx[k]
                y = xyz[r, c, 1] - my[k]
                for j in range(n_ang):
                    u = x * ca[j] + y * sa[j]
                    v = -x * sa[j] + y * ca[j]
                    lo_a[i, j, 0] = min(lo_a[i, j, 0], u)
                    hi_a[i, j, 0] = max(hi_a[i, j, 0], u)
                    lo_a[i, j, 1] = min(lo_a[i, j, 1], v)
                    hi_a[i, j, 1] = max(hi_a[i, j, 1], v)
        for k in range(1, n + 1):
            if cnt[k] == 0 or not area[k]:
                continue
            i = at[k]
            best = np.inf
            for j in range(n_ang):
                a = hi_a[i, j, 0] - lo_a[i, j, 0]
                b = hi_a[i, j, 1] - lo_a[i, j, 1]
                if a * b < best:
                    best = a * b
                    length[k] = max(a, b)
                    width[k] = min(a, b)
    return cnt, hlo, hhi, top90, length, width, thick, rough, n_rough


@njit(cache=True, nogil=True)
def first_returns(lines, valid):
    """The first valid slot of every line that has one (``lines``: int64 (L, n), ``-1`` pads)."""
    out = np.empty(lines.shape[0], np.int64)
    m = 0
    for li in range(lines.shape[0]):
        for j in range(lines.shape[1]):
            s = lines[li, j]
            if s < 0:
                break
            if valid[s]:
                out[m] = s
                m += 1
                break
    return out[:m]


@njit(cache=True, nogil=True)
def _column_ground(xyz, valid, lines, zd, tol, slope, max_step, eps):
    """:func:`column_ground` along every line at once, step ``j`` of all lines before step ``j + 1``
    (``lines``: (L, n)): a spinning sensor's step ``j`` is one beam's ring, contiguous in memory, where
    one line after the other jumped a ring's length at every step. (The line array is read across its
    rows, a stride the cache holds, instead of being copied transposed every sweep.)"""
    n_lines, n_steps = lines.shape
    ground = np.zeros(xyz.shape[0], np.bool_)
    height = np.full(n_lines, zd)
    last = np.full(n_lines, -1, np.int64)
    last_rho = np.zeros(n_lines)
    ended = np.zeros(n_lines, np.bool_)
    for j in range(n_steps):
        for li in range(n_lines):
            if ended[li]:
                continue
            s = lines[li, j]
            if s < 0:
                ended[li] = True
                continue
            if not valid[s]:
                continue
            rho = np.sqrt(xyz[s, 0] ** 2 + xyz[s, 1] ** 2)
            k = last[li]
            if k < 0:
                if abs(xyz[s, 2] - zd) < tol:
                    ground[s] = True
                    height[li] = xyz[s, 2]
                    last[li] = s
                    last_rho[li] = rho
                continue
            dh = rho - last_rho[li]
            if dh > 0 and abs(xyz[s, 2] - xyz[k, 2]) <= min(slope * dh, max_step) + eps:
                ground[s] = True
                last[li] = s
                last_rho[li] = rho
    return ground, height


def column_ground(
    scan: Scan,
    lines: np.ndarray,
    rel_tolerance: float = 0.10,
    max_slope: float = 10.0,
    max_step: float = 0.2,
    min_share: float = 0.3,
):
    """Ground along the column profile for sensors whose columns are too short for Sec. 5 part
    (a) (a 16-beam column holds fewer than its 10 consecutive horizontal returns).

    Sec. 5 part (b) with one estimate per column: ``z_i`` is the column's first return, ``z_d``
    the lowest mean-shift mode of the ``z_i`` (0.2 m bandwidth) that holds at least ``min_share`` of
    them (the ground is the lowest wide surface; the main mode was the wrong one where a 16-beam
    sensor's lowest beam meets parked cars and facades before the ground: a walker on the simulated
    street's sidewalk, z_d on the car sides 0.9 m up, ground recall 0.00); a column's first return within the
    paper's 10 % of ``|z_d|`` starts its ground, and each later return continues it when it lies
    farther out and at most ``max_slope`` (plus 5 cm of noise), and never more than ``max_step``
    (Sec. 6's tallest curb), above or below the last ground return: the line angles of Sec. 3
    staying collinear, read across an occlusion too.

    Returns
    -------
    ground : bool (rows, cols); heights : float64 per line (``z_i``, else ``z_d``); zd : float or None
    """
    from prc_slam.online.ground import mean_shift_modes

    xyz = scan.slot_xyz64()
    valid = scan.valid.ravel()
    first = first_returns(lines, valid)
    if len(first) == 0:
        return np.zeros(scan.shape, bool), np.zeros(len(lines)), None
    # z_d from at most ~128 columns spread over the sweep (the mode search is quadratic in its samples)
    modes, counts = mean_shift_modes(xyz[first[:: max(1, len(first) // 128)], 2], 0.2)
    wide = modes[counts >= min_share * counts.sum()]
    zd = float(wide.min()) if len(wide) else float(modes[0])
    ground, height = _column_ground(
        xyz, valid, np.asarray(lines, dtype=np.int64), zd, rel_tolerance * abs(zd), np.tan(np.radians(max_slope)),
        max_step, 0.05,
    )  # fmt: skip
    return ground.reshape(scan.shape), height, zd


@njit(cache=True, nogil=True)
def grow_down(inst, valid, xyz, height, alt, floor, min_gate):
    """A car reaches down to the ground (Sec. 7: car returns start at the ground): below every car
    return, the next returns down its column join its car while they lie above ``floor`` over the
    local ground and within ``min_gate`` of the return above (rows in elevation order, lowest
    first). Returns the grown instance image."""
    R, C = inst.shape
    out = inst.copy()
    for r in range(R - 1, 0, -1):  # each column top down (rows outside: image order in memory)
        for c in range(C):
            k = out[r, c]
            if k == 0 or not valid[r, c]:
                continue
            r1 = r - 1
            while r1 >= 0 and not valid[r1, c]:
                r1 -= 1
            if r1 < 0 or out[r1, c] != 0 or height[r1, c] < floor:
                continue
            if _d2(xyz, r, c, r1, c) <= min_gate * min_gate:
                out[r1, c] = k
    return out


@dataclass
class SpinningCars:
    """Car returns of one sweep and the segment evidence behind them."""

    mask: np.ndarray  # bool (rows, cols)
    instances: np.ndarray  # int32 (rows, cols), 0 = no car, 1.. = car instance
    boxes: list[dict] = field(default_factory=list)
    segments: np.ndarray | None = None  # int32 (rows, cols): every candidate segment
    features: dict[str, np.ndarray] = field(default_factory=dict)  # per segment, index 0 unused
    accepted: np.ndarray | None = None  # bool per segment (on its own, before step 5b)
    merged: int = 0  # cars made of a face and the roof above it (step 5b)


@njit(cache=True, nogil=True)
def _local_ground(lines, ground, z, line_height, lo, hi, out):
    """:func:`local_ground` of lines ``lo..hi - 1``, written into ``out``."""
    for li in range(lo, hi):
        h = line_height[li]
        for j in range(lines.shape[1]):
            s = lines[li, j]
            if s < 0:
                break
            if ground[s]:
                h = z[s]
            out[s] = h


def local_ground(lines: np.ndarray, ground: np.ndarray, z: np.ndarray, line_height: np.ndarray) -> np.ndarray:
    """Ground height under every slot (step 1): the height of the last ground return before it in
    its scan line (a spinning sensor's column, lowest beam first), else the line's own height.

    Parameters
    ----------
    lines : int64 (L, n), flat slot indices per scan line (``-1`` pads)
    ground : bool, flat per slot
    z : float, flat per slot
    line_height : float (L,), fallback per line

    Returns
    -------
    float64, flat per slot (NaN for slots on no line)
    """
    lines = np.ascontiguousarray(lines, dtype=np.int64)
    ground = np.ascontiguousarray(ground, dtype=np.bool_)
    z = np.asarray(z, dtype=np.float64)  # a strided view is fine (e.g. the z column of slot_xyz64)
    line_height = np.ascontiguousarray(line_height, dtype=np.float64)
    out = np.full(ground.shape[0], np.nan)
    in_threads(lambda lo, hi: _local_ground(lines, ground, z, line_height, lo, hi, out), lines.shape[0])
    return out


@njit(cache=True, nogil=True)
def grazing_links(seg, valid, xyz, min_rise, max_run):
    """Pairs of segments one above the other in a column across a grazing surface (step 5b).

    For every column top of a segment (rows in elevation order, lowest first) that ends a vertical
    face of it (the segment's return below lies at most as far out as it lies lower: steeper than
    45 deg), the next valid return up the column (missing slots skipped) that belongs to another
    segment, lies farther out by at most ``max_run`` (horizontally; less ``min_rise`` of noise) and
    no lower, links the two: a car's body and its roof or bonnet, which a beam meets at a grazing
    angle, metres farther out. Rising terrain has no vertical face and links nothing.

    Returns ``(low, up)`` segment ids, one entry per linking column (in image order)."""
    R, C = seg.shape
    low = np.empty(R * C, np.int64)
    up = np.empty(R * C, np.int64)
    m = 0
    for r in range(R):  # image order in memory (each column is read upwards from every slot)
        for c in range(C):
            k = seg[r, c]
            if k == 0:
                continue
            r1 = r + 1
            while r1 < R and not valid[r1, c]:
                r1 += 1
            if r1 >= R:
                continue
            k1 = seg[r1, c]
            if k1 == 0 or k1 == k:
                continue
            # the lower part ends in a vertical face (Sec. 7.2's V): the return below it in the
            # column, of the same segment, lies at most as far out as it lies lower
            r0 = r - 1
            while r0 >= 0 and not valid[r0, c]:
                r0 -= 1
            if r0 < 0 or seg[r0, c] != k:
                continue
            rho0 = np.sqrt(xyz[r, c, 0] ** 2 + xyz[r, c, 1] ** 2)
            rho_b = np.sqrt(xyz[r0, c, 0] ** 2 + xyz[r0, c, 1] ** 2)
            if abs(rho0 - rho_b) > xyz[r, c, 2] - xyz[r0, c, 2]:
                continue
            rho1 = np.sqrt(xyz[r1, c, 0] ** 2 + xyz[r1, c, 1] ** 2)
            if -min_rise <= rho1 - rho0 <= max_run and xyz[r1, c, 2] >= xyz[r, c, 2]:
                low[m] = k
                up[m] = k1
                m += 1
    return low[:m], up[:m]


@njit(cache=True, nogil=True)
def segment_counts(seg, n, mask):
    """Per id ``0..n`` of ``seg`` (rows, cols): how many of its slots are set in ``mask``."""
    cnt = np.zeros(n + 1, np.int64)
    R, C = seg.shape
    for r in range(R):
        for c in range(C):
            if mask[r, c]:
                cnt[seg[r, c]] += 1
    return cnt


@njit(cache=True, nogil=True)
def segment_tops(seg, n, height, vegetation):
    """Per id ``0..n`` of ``seg`` (rows, cols): the flat index of the highest return of the id
    (the last in flat order among equal heights; 0 for an id without slots), the number of its
    slots and how many of them are ``vegetation``, in one pass over the image. ``height`` must
    be finite where ``seg`` > 0."""
    R, C = seg.shape
    top_at = np.zeros(n + 1, np.int64)
    best = np.full(n + 1, -np.inf)
    cnt = np.zeros(n + 1, np.int64)
    veg = np.zeros(n + 1, np.int64)
    for r in range(R):
        for c in range(C):
            k = seg[r, c]
            cnt[k] += 1
            if vegetation[r, c]:
                veg[k] += 1
            if k != 0 and height[r, c] >= best[k]:
                best[k] = height[r, c]
                top_at[k] = r * C + c
    return top_at, cnt, veg.astype(np.float64)


@njit(cache=True, nogil=True)
def segment_tops_within(seg, n, height, vegetation, rng, local_gap, resolution, valid):
    """:func:`segment_tops` over the returns a column resolves only: those whose column neighbours lie at
    most ``resolution`` apart (``range x local_gap`` of their row, ``rng`` the ranges) count as slots, and
    as ``vegetation`` (what :func:`segment_tops` of ``vegetation & resolved`` and :func:`segment_counts` of
    ``resolved`` give), in one pass over the image with no mask made."""
    R, C = seg.shape
    top_at = np.zeros(n + 1, np.int64)
    best = np.full(n + 1, -np.inf)
    cnt = np.zeros(n + 1, np.int64)
    veg = np.zeros(n + 1, np.int64)
    for r in range(R):
        g = local_gap[r]
        for c in range(C):
            k = seg[r, c]
            if np.float64(rng[r, c]) * g <= resolution and valid[r, c]:
                cnt[k] += 1
                if vegetation[r, c]:
                    veg[k] += 1
            if k != 0 and height[r, c] >= best[k]:
                best[k] = height[r, c]
                top_at[k] = r * C + c
    return top_at, cnt, veg.astype(np.float64)


def missing_top_gaps(
    valid: np.ndarray, alt: np.ndarray, gaps: np.ndarray, mount: float, max_range: float, at: np.ndarray | None = None
) -> np.ndarray:
    """Per slot (rows in elevation order, lowest first): the elevation (rad) from its beam up to the next
    beam of its column with a return, across beams that returned nothing although they point down
    enough to meet the ground within ``max_range`` from ``mount`` above it (they met a surface that
    sent nothing back); where a beam in between could have passed into the sky (or none lies above),
    the gap to the next beam, ``gaps`` (rows,).

    Parameters
    ----------
    valid : ndarray of bool, shape (rows, cols)
    alt : ndarray, shape (rows,)
        Beam elevations (rad), ascending.
    gaps : ndarray, shape (rows,)
        ``alt[r + 1] - alt[r]`` (0 for the highest beam).
    mount : float
        Sensor height above the ground (m).
    max_range : float
        Farthest return of the sweep (m).
    at : ndarray of int, optional
        Flat slot indices: the gaps of those slots only, shape ``at.shape`` (default: every slot,
        shape (rows, cols)).
    """
    rows, cols = valid.shape
    if alt.shape != (rows,) or gaps.shape != (rows,):
        raise ValueError(f"alt {alt.shape} and gaps {gaps.shape} must hold one value per row ({rows})")
    reach = np.where(alt < 0, mount / np.tan(-np.minimum(alt, -1e-9)), np.inf)
    should_hit = (alt < 0) & (reach < max_range)  # per row
    idx = np.arange(rows * cols) if at is None else np.asarray(at, dtype=np.int64).ravel()
    out = _missing_top_gaps(
        valid, np.asarray(alt, dtype=np.float64), np.asarray(gaps, dtype=np.float64), should_hit, idx
    )
    return out.reshape((rows, cols) if at is None else np.shape(at))


@njit(cache=True, nogil=True)
def _missing_top_gaps(valid, alt, gaps, should_hit, idx):
    """:func:`missing_top_gaps` of the flat slots ``idx``, given per row whether its beam must have met a
    surface (``should_hit``): up each slot's column to the first return, across beams that must have."""
    rows, cols = valid.shape
    out = np.empty(idx.shape[0])
    for i in range(idx.shape[0]):
        r0, c = idx[i] // cols, idx[i] % cols
        out[i] = gaps[r0]
        for r in range(r0 + 1, rows):
            if valid[r, c]:
                out[i] = alt[r] - alt[r0]
                break
            if not should_hit[r]:
                break
    return out


def _judge(
    seg_o, n, high_touch, tops, xyz, height, valid, rng, gaps, vegetation, p, floor=None, resolved=None, top_gaps=None
):
    """Steps 4-6 on the segments 1..n of ``seg_o`` (rows in elevation order): the accepted mask
    per segment (index 0 unused, False) and the features behind it. The roof test allows for the
    gap above each segment's highest return: ``gaps`` per row (to the next beam), or ``top_gaps``, a
    function of flat slot indices (:func:`missing_top_gaps`); the feature ``roof_next`` is the roof with
    the next beam's gap. ``resolved`` (``veg_resolution``): ``(local_gap, resolution)``, the vegetation
    share taken over the returns whose ``range x local_gap`` (per row) is at most ``resolution``
    (:func:`segment_tops_within`)."""
    cnt, hlo, hhi, top90, length, width, thick, rough, n_rough = segment_features(
        seg_o, n, xyz, height, valid, p.ring_baseline, p.min_area, p.min_points, p.max_top, p.max_bottom, floor
    )
    share = high_touch / np.maximum(tops, 1)
    cols = seg_o.shape[1]
    if resolved is None:
        top_at, cnt_all, veg = segment_tops(seg_o, n, height, vegetation)
    else:  # the share over the returns the column statistic resolves, if enough of them
        top_at, cnt_all, veg = segment_tops_within(seg_o, n, height, vegetation, rng, *resolved, valid)
        veg = np.where(cnt_all >= p.min_points, veg, 0.0)
    top_rng = rng[top_at // cols, top_at % cols]  # (no flat copy of a reordered range image)
    next_gap = top_rng * np.abs(gaps[top_at // cols])
    top_gap = next_gap if top_gaps is None else top_rng * np.abs(top_gaps(top_at))
    veg_share = veg / np.maximum(cnt_all, 1)
    roof = hhi + np.minimum(top_gap, p.max_top_gap)
    ok = (
        (cnt >= p.min_points)
        & (roof >= p.min_top)
        & (top90 <= p.max_top)
        & (hlo <= p.max_bottom)
        & (length <= p.max_length)
        & (length >= p.min_length)
        & (width <= p.max_width)
        & (thick >= p.min_thickness)
        & (share <= p.high_share)
        & (rough <= p.max_roughness)
        & (n_rough >= p.min_ring_triples)
        & (veg_share <= p.max_vegetation)
    )
    ok[0] = False
    feats = dict(
        points=cnt, bottom=hlo, top=hhi, top90=top90, length=length, width=width, thickness=thick, roughness=rough,
        high_share=share, ring_triples=n_rough, vegetation=veg_share, roof=roof,
        roof_next=hhi + np.minimum(next_gap, p.max_top_gap),
    )  # fmt: skip
    return ok, feats


def _merge_grazing(
    seg_o, n, ok, bottom, roof, high, alt, xyz, height, valid, rng, gaps, vegetation, p, floor=None, resolved=None,
    top_gaps=None,
):  # fmt: skip
    """Step 5b: a face (a segment standing on the ground, its lowest return within ``max_bottom``,
    but too low for a car: ``roof``, its top plus the beam gap allowance, under ``min_top``) and
    the segments above it (a roof, a bonnet) linked to it across a grazing surface on at least
    ``grazing_links`` columns form one candidate; an upper part linked to two faces joins neither
    (a roof spans no two cars), and no upper part is another's face (no chains). The candidate
    replaces its parts when it passes steps 4-6 as a whole, otherwise every part keeps its own
    verdict. Returns the instance image (rows in elevation order, 0 = no car, ids 1..) and the
    number of merged cars."""
    remap = np.zeros(n + 1, np.int32)
    remap[ok] = np.arange(1, int(ok.sum()) + 1)
    if p.grazing_links <= 0 or n < 2:
        return relabel(seg_o, remap), 0
    low, up = grazing_links(seg_o, valid, xyz, p.min_gate, p.max_length)
    face = (bottom <= p.max_bottom) & (roof < p.min_top)  # stands on the ground, too low for a car
    sel = face[low]
    low, up = low[sel], up[sel]
    if len(low) == 0:
        return relabel(seg_o, remap), 0
    pair, votes = np.unique(low * (n + 1) + up, return_counts=True)
    keep = votes >= p.grazing_links
    a, b = pair // (n + 1), pair % (n + 1)
    lows_of_up = np.bincount(b[keep], minlength=n + 1)
    keep &= lows_of_up[b] == 1  # a roof spans no two cars
    keep &= ~np.isin(b, a[keep])  # no chains: a face's roof is no other roof's face
    if not keep.any():
        return relabel(seg_o, remap), 0
    comp = graph_components(n + 1, a[keep], b[keep])
    size = np.bincount(comp, minlength=n + 1)
    # groups of two or more parts, numbered 1..g; lone segments keep their verdict
    multi = size[comp] > 1
    multi[0] = False
    gid = np.zeros(n + 1, np.int64)
    groups, gid[multi] = np.unique(comp[multi], return_inverse=True)
    gid[multi] += 1
    g = len(groups)
    seg_g = relabel(seg_o, gid.astype(np.int32))
    ht_g, tops_g = outline_tops(
        seg_g, g, valid, high, xyz, rng, alt, p.min_gate, p.gate_factor, p.max_gate, height, p.top_floor,
        p.top_width, p.high_steep, p.top_height,
    )  # fmt: skip
    ok_g, _ = _judge(seg_g, g, ht_g, tops_g, xyz, height, valid, rng, gaps, vegetation, p, floor, resolved, top_gaps)
    # final ids: accepted groups first, then accepted segments outside an accepted group
    take_g = ok_g[gid] & multi
    alone = ok & ~take_g
    final = np.zeros(n + 1, np.int64)
    final[alone] = np.arange(1, int(alone.sum()) + 1)
    gnum = np.zeros(g + 1, np.int64)
    gnum[ok_g] = np.arange(1, int(ok_g.sum()) + 1) + int(alone.sum())
    final[take_g] = gnum[gid[take_g]]
    return relabel(seg_o, final.astype(np.int32)), int(ok_g[1:].sum())


@njit(cache=True, nogil=True)
def _heights(z, zg, valid, ground, min_above, max_height):
    """Per slot: the height above the local ground ``zg`` (``-inf`` where it is NaN), the
    candidates of step 2 (valid, not ground, ``min_above`` to ``max_height`` high), the returns
    above ``max_height``, and the height with non-finite values as 0 and as ``-inf``."""
    R, C = z.shape
    height = np.empty((R, C))
    cand = np.empty((R, C), np.bool_)
    high = np.empty((R, C), np.bool_)
    h_zero = np.empty((R, C))
    h_down = np.empty((R, C))
    for r in range(R):
        for c in range(C):
            g = zg[r, c]
            h = np.float64(z[r, c]) - (np.inf if np.isnan(g) else g)
            height[r, c] = h
            cand[r, c] = valid[r, c] and not ground[r, c] and h >= min_above and h <= max_height
            high[r, c] = valid[r, c] and h > max_height
            fin = np.isfinite(h)
            h_zero[r, c] = h if fin else 0.0
            h_down[r, c] = h if fin else -np.inf
    return height, cand, high, h_zero, h_down


@njit(cache=True, nogil=True)
def hidden_floor(seg, xyz, zg, rng, tan_low, below_lowest, gap_down):
    """Per slot of a segment (``seg`` > 0; rows in elevation order, lowest first; other slots 0, which
    step 5 does not read): how far above the local ground ``zg`` step 5 measures a segment's bottom
    from. ``below_lowest`` (``hidden_floor``): where the lowest beam (``tan_low``, the tangent of its
    elevation) passes at the slot's horizontal distance, at least 0 (0 where not finite); plus, with
    ``gap_down`` (the gap to the next beam down per row; empty: none, ``bottom_gap``), ``range x`` that
    gap. One pass; each value as the elementwise numpy expressions give it (the horizontal distance in
    float32, as ``np.hypot`` of the float32 coordinates)."""
    R, C = rng.shape
    out = np.zeros((R, C))
    with_gap = gap_down.shape[0] > 0
    for r in range(R):
        for c in range(C):
            if seg[r, c] == 0:
                continue
            v = 0.0
            if below_lowest:
                v = np.float64(np.hypot(xyz[r, c, 0], xyz[r, c, 1])) * tan_low - zg[r, c]
                v = v if np.isfinite(v) and v > 0.0 else 0.0  # +0.0 for -0.0 too, as np.maximum gives
            if with_gap:
                v = v + np.float64(rng[r, c]) * gap_down[r]
            out[r, c] = v
    return out


def detect_cars_spinning(
    scan: Scan,
    ground: np.ndarray,
    lines: np.ndarray,
    line_height: np.ndarray,
    vegetation: np.ndarray | None = None,
    params: SpinningCarParams | None = None,
    zg: np.ndarray | None = None,
) -> SpinningCars:
    """Cars of one sweep of a spinning sensor (module docstring), given the ground mask, the scan
    lines (columns, lowest beam first), each line's ground height, optionally the coarse
    classifier's vegetation mask and the :func:`local_ground` of every slot (computed if None)."""
    if not isinstance(scan.sensor, SpinningSensor):
        raise TypeError(
            f"{scan.source}: detect_cars_spinning needs a spinning sensor, got {type(scan.sensor).__name__}"
        )
    p = params or SpinningCarParams()
    sensor = scan.sensor
    vegetation = np.zeros(scan.shape, bool) if vegetation is None else vegetation
    rows, cols = scan.shape
    xyz = scan.slot_xyz()
    valid = scan.valid
    if zg is None:
        zg = local_ground(lines, ground.ravel(), xyz[..., 2].ravel(), line_height)
    height, cand, high, h_zero, h_down = _heights(
        xyz[..., 2], zg.reshape(rows, cols), valid, ground, p.min_above_ground, p.max_height
    )
    order = np.argsort(sensor.altitude, kind="stable")  # rows by elevation, lowest first
    alt = np.ascontiguousarray(sensor.altitude[order])
    # views when the rows are already in (reversed) elevation order, as most readers give them
    by_elevation = elevation_rows(sensor.altitude)
    o_xyz = xyz[by_elevation]
    o_valid = valid[by_elevation]
    o_h = height[by_elevation]
    cand = cand[by_elevation]
    high = high[by_elevation]
    rng = scan.ranges[by_elevation]
    seg_o, n, high_touch, tops = segment_candidates(
        cand, o_valid, high, o_xyz, rng, 2.0 * np.pi / cols, alt,
        p.min_gate, p.gate_factor, p.max_gate, p.see_through, int(p.diagonal), o_h, p.top_floor,
        p.top_width, p.high_steep, p.top_height,
    )  # fmt: skip
    h_o = h_zero[by_elevation]
    veg_o = vegetation[by_elevation]
    # the top is seen up to one beam gap below the object's top (a 16-beam sensor's 2 deg are 0.5 m
    # at 15 m): the roof test allows for the gap above the highest return of each segment
    gaps = np.empty(rows)
    gaps[:-1] = np.diff(alt) if rows > 1 else 0.0
    gaps[-1] = 0.0
    top_gaps = None
    if p.missing_top and rows > 1:
        # above a segment's highest return, beams that return nothing although they would meet the ground within
        # the sweep's range met a surface that sent nothing back (glass, dark paint): the roof test allows for the
        # gap up to the next beam with a return, not just the next beam (step 5)
        heights = np.asarray(line_height, dtype=np.float64)
        heights = heights[np.isfinite(heights)]
        mount = -float(np.median(heights)) if len(heights) else 0.0
        far = float(scan.ranges.max())

        def top_gaps(at: np.ndarray) -> np.ndarray:  # at the segments' highest returns only
            return missing_top_gaps(o_valid, alt, gaps, mount, far, at)

    floor = None
    bottom_gap = p.bottom_gap and rows > 1
    if p.hidden_floor or bottom_gap:
        # hidden_floor: a narrow field of view (an OS2's lowest beam at -11.25 deg passes 0.9 m above the road
        # 5 m out) does not see a near car's lower body: its bottom is measured from where the lowest beam
        # passes (step 5, "cars stand on the ground", as far as the sensor can tell).
        # bottom_gap: the next beam down passes range x gap below a segment's lowest return and missed the
        # object: its body may reach down that far, unseen (a 32-beam sensor's 1.33 deg are 0.6 m at 25 m); step
        # 5's bottom is taken from there, the slot spacing up a column at that range, as the gates of step 3
        # scale with it
        gap_down = np.abs(np.concatenate([gaps[:1], gaps[:-1]])) if bottom_gap else np.zeros(0)
        floor = hidden_floor(
            seg_o, o_xyz, zg.reshape(rows, cols)[by_elevation], rng, np.tan(alt[0]), p.hidden_floor, gap_down
        )
    resolved = None
    if p.veg_resolution > 0 and rows > 1:
        # step 6's vegetation share only over returns whose column neighbours lie closer than veg_resolution
        # (range x beam gap): beyond, a column crosses a car with a handful of returns, each near an edge
        # (ground to body, body to glass, roof to background), and the coarse classifier's fast switching
        # is the sampling's, not the surface's (the returns are picked as step 6 counts them)
        resolved = (np.abs(np.concatenate([gaps[:-1], gaps[-2:-1]])), float(p.veg_resolution))
    ok, feats = _judge(
        seg_o, n, high_touch, tops, o_xyz, h_o, o_valid, rng, gaps, veg_o, p, floor, resolved, top_gaps
    )  # fmt: skip
    # step 5b's faces are too low for a car by the next beam's gap (their roof, seen or not, is what a merge adds)
    inst_o, merged = _merge_grazing(
        seg_o, n, ok, feats["bottom"], feats["roof_next"], high, alt, o_xyz, h_o, o_valid, rng, gaps, veg_o, p,
        floor, resolved, top_gaps,
    )  # fmt: skip
    if p.down_to > 0:
        inst_o = grow_down(inst_o, o_valid, o_xyz, h_down[by_elevation], alt, p.down_to, p.min_gate)
    seg = np.empty_like(seg_o)
    seg[order] = seg_o
    instances = np.empty_like(inst_o)
    instances[order] = inst_o
    mask = instances > 0
    boxes = oriented_boxes(instances, xyz)
    return SpinningCars(mask, instances, boxes, seg, feats, ok, merged)


def oriented_boxes(instances: np.ndarray, xyz: np.ndarray) -> list[dict]:
    """One oriented box per instance id 1..n of ``instances`` (rows, cols) from ``xyz`` (rows,
    cols, 3): centre xyz, size (length along the footprint's principal axis, width, height), yaw
    of that axis (rad), point count (:func:`~prc_slam.online.car.oriented_box`, in one kernel)."""
    return oriented_boxes_of(instances.ravel(), xyz.reshape(-1, 3))


@njit(cache=True, nogil=True)
def _ground_run(zg, alt_a, alt_b):
    """The horizontal run between where beams of elevation ``alt_a`` < ``alt_b`` (rad) meet level
    ground ``zg`` below the sensor (m, negative): ``|zg| (cot|alt_b| - cot|alt_a|)``, the expected
    slot spacing along a column there; 0 when either beam does not reach the ground."""
    if not (zg < 0 and alt_a < alt_b < 0):
        return 0.0
    return -zg * (1.0 / np.tan(-alt_b) - 1.0 / np.tan(-alt_a))


@njit(cache=True, nogil=True)
def _curb_faces(
    xyz, valid, lines, zg, steep, ground_tol, min_rise, t_curb, max_step, alt, cols, relative, top_tol, min_step,
    max_spacing,
):  # fmt: skip
    """Curb-face returns along each column (see :func:`detect_curbs_spinning`; ``alt``: each row's beam
    elevation (rad), ``cols``: the sweep's columns, ``relative``: the first step's run counted beyond the
    run the two beams would have on level ground, ``top_tol``: returns within it of the top are no face)."""
    face = np.zeros(xyz.shape[0], np.bool_)
    pts = np.empty(lines.shape[1], np.int64)
    rho = np.empty(lines.shape[1])  # horizontal distance of each return of the line
    for li in range(lines.shape[0]):
        line = lines[li]
        n = 0
        for j in range(line.shape[0]):
            s = line[j]
            if s < 0:
                break
            if valid[s]:
                pts[n] = s
                rho[n] = np.sqrt(xyz[s, 0] ** 2 + xyz[s, 1] ** 2)
                n += 1
        j = 1
        while j < n:
            a, k = pts[j - 1], pts[j]
            dz = xyz[k, 2] - xyz[a, 2]
            # a NaN local ground fails the level test, as the infinite one did
            if not (dz > min_step and abs(xyz[a, 2] - zg[a]) < ground_tol):
                j += 1
                continue
            run = abs(rho[j] - rho[j - 1])
            # less the run of the two beams on level ground: a step within one beam gap is steep, where the beams
            # lie at most max_spacing apart up a vertical surface there
            if relative and rho[j] * abs(alt[k // cols] - alt[a // cols]) <= max_spacing:
                run = max(0.0, run - _ground_run(zg[a], alt[a // cols], alt[k // cols]))
                if j >= 2 and rho[j - 1] > rho[j - 2] and rho[j] > rho[j - 1]:  # less the grade the column climbs to a
                    grade = (xyz[a, 2] - xyz[pts[j - 2], 2]) / (rho[j - 1] - rho[j - 2])
                    dz -= max(grade, 0.0) * (rho[j] - rho[j - 1])
            # a steep step up from a return at the local ground level starts a possible face
            if not (dz > min_step and dz > steep * run):
                j += 1
                continue
            base = xyz[a, 2]
            e = j
            while e + 1 < n:  # the face goes on while the steps stay steep, short and low
                b = pts[e + 1]
                q = pts[e]
                dzb = xyz[b, 2] - xyz[q, 2]
                if dzb > 0 and dzb > steep * abs(rho[e + 1] - rho[e]) and xyz[b, 2] - base <= t_curb + 0.05:
                    e += 1
                else:
                    break
            top = xyz[pts[e], 2]
            # the top of the face continues flat (the sidewalk) or the column ends
            flat = True
            if e + 1 < n:
                b = pts[e + 1]
                q = pts[e]
                flat = abs(xyz[b, 2] - xyz[q, 2]) <= max_step + 0.2 * abs(rho[e + 1] - rho[e])
                # the surface the face leads up to, when the column reaches it within twice its beams' run on
                # level ground (beyond: an occlusion, a facade's foot)
                near = abs(rho[e + 1] - rho[e]) <= max(2.0 * _ground_run(zg[q], alt[q // cols], alt[b // cols]), 0.5)
                if flat and near and top_tol >= 0:
                    top = max(top, xyz[b, 2])
            rise = top - base
            if min_rise <= rise <= t_curb and flat:
                for q in range(j, e + 1):
                    if top_tol < 0 or xyz[pts[q], 2] < top - top_tol:
                        face[pts[q]] = True
            j = e + 1
    return face


def detect_curbs_spinning(
    scan: Scan,
    lines: np.ndarray,
    ground: np.ndarray,
    line_height: np.ndarray,
    t_curb: float = 0.2,
    min_rise: float = 0.05,
    min_lines: int = 3,
    link: float = 0.5,
    steep: float = 0.5,
    ground_tol: float = 0.1,
    zg: np.ndarray | None = None,
    relative: bool = True,
    top_tol: float = 0.02,
    min_step: float = 0.02,
    max_spacing: float = 0.4,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Curb faces of a spinning sensor's sweep: Sec. 6 with the column's own steps as "vertical".

    A 64-beam column crosses a 10-15 cm curb face with one to three returns, too few for the
    coarse classifier's CUSUM to turn vertical (Sec. 4), so Sec. 6 (a) finds no possible curb
    point there. Here a face starts at a step up steeper than ``steep`` (rise over run, 0.5: 27 deg,
    where the road's camber and noise stay below 10 deg) from a return within ``ground_tol`` of the
    local ground level (:func:`local_ground`), goes on while the steps stay steep, and is a possible curb
    when it rises between ``min_rise`` and ``t_curb`` (0.2 m, Sec. 6) and the column continues flat
    on top (the sidewalk). Part (b): faces within ``link`` (0.5 m voxels, 26-connected) form
    regions; a region seen on at least ``min_lines`` columns (Sec. 6: three scan lines) whose
    height stays within ``t_curb`` is a curb. Returns the curb mask (rows, cols) and one polyline
    per curb (the mean return of each column, in column order), sensor frame.

    Scaled to the beam spacing (``relative``; False with ``top_tol < 0``: the steps in metres as
    above). Beyond a few metres a column meets the face with one return, 0.4-3 m after the last road
    return: the run between two beams on level ground, ``|z_g| (cot|a_k| - cot|a_a|)``
    (:func:`_ground_run`), the expected slot spacing there. The first step's run is counted beyond
    that run, so a rise within one beam gap is steep, where the two beams lie at most ``max_spacing``
    apart up a vertical surface (range x gap; farther apart a face is not resolved); its rise must
    exceed ``min_step`` (the road's noise) after taking off what the grade from the return before
    predicts (a sloping road or sidewalk climbs steadily, a curb in one step). The rise is measured
    to the surface the face leads up to, the next return when it continues flat within twice its
    beams' ground run (a face return halfway up is followed by the sidewalk, not by more face), and
    only returns more than ``top_tol`` below that top are face (the first sidewalk return is not).
    Street seeds 0-2 (the parameter-choosing seeds, 3 sweeps each), curb F1 before -> after:
    hdl64 0.59 / 0.36 / 0.66 -> 0.70 / 0.56 / 0.70, hdl32 0.12 / 0.10 / 0.22 -> 0.50 / 0.16 / 0.65,
    os1-64 0.26 / 0.24 / 0.34 -> 0.48 / 0.47 / 0.39, os0-128 0.47 / 0.15 / 0.30 -> 0.47 / 0.12 / 0.60,
    os2-128 0.28 / 0.46 / 0.36 -> 0.26 / 0.58 / 0.42.
    """
    from prc_slam.online.curb import _polylines
    from prc_slam.util.voxels import VoxelGrid

    rows, cols = scan.shape
    xyz = scan.slot_xyz64()
    valid = scan.valid.ravel()
    if zg is None:
        zg = local_ground(lines, ground.ravel(), xyz[:, 2], line_height)
    zg = np.ascontiguousarray(zg.ravel(), dtype=np.float64)  # NaN: no ground level (fails the level test)
    alt = np.asarray(scan.sensor.altitude, dtype=np.float64)
    face = _curb_faces(
        xyz, valid, lines, zg, steep, ground_tol, min_rise, t_curb, 0.05, alt, cols, relative, top_tol,
        min_step if relative else 0.0, max_spacing,
    )  # fmt: skip
    mask = np.zeros(rows * cols, bool)
    members = np.flatnonzero(face)
    if len(members) == 0:
        return mask.reshape(rows, cols), []
    grid = VoxelGrid.build(xyz[members], link)
    grid_comp = grid.components()[grid.voxel]
    col = members % cols
    n = grid_comp.max() + 1
    pairs = np.unique(grid_comp.astype(np.int64) * cols + col)
    n_cols = np.bincount(pairs // cols, minlength=n)
    z = xyz[members, 2]
    zmin = np.full(n, np.inf)
    zmax = np.full(n, -np.inf)
    np.minimum.at(zmin, grid_comp, z)
    np.maximum.at(zmax, grid_comp, z)
    ok = (n_cols >= min_lines) & (zmax - zmin <= t_curb)
    mask[members[ok[grid_comp]]] = True
    mask = mask.reshape(rows, cols)
    regions = np.zeros(rows * cols, np.int32)
    regions[members] = grid_comp + 1
    ok_r = np.concatenate(([False], ok))
    line_index = np.broadcast_to(np.arange(cols)[None, :], (rows, cols))
    return mask, _polylines(regions.reshape(rows, cols), ok_r, line_index, xyz.reshape(rows, cols, 3))
