"""Procedural scenes: an urban street and a forest plot, from a seed.

Both are triangle meshes (:class:`~data_tools.sim.mesh.Mesh`) with a class code and an
instance id per triangle. The urban street follows a centreline with straights and turns;
the forest plot is uneven terrain with stems along a walking path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from data_tools.sim.mesh import DARK, GLASS, Mesh, MeshBuilder
from prc_slam import labels as L


@dataclass
class Centerline:
    """A planar path sampled every ``step`` metres: positions, headings, and a height profile."""

    xy: np.ndarray
    heading: np.ndarray
    z: np.ndarray
    step: float

    @classmethod
    def from_segments(
        cls, segments: list[tuple[str, float, float]], step: float = 0.5, z_amp: float = 1.5, z_wave: float = 90.0
    ) -> Centerline:
        """Build from ``("straight", length, 0)`` and ``("turn", angle_deg, radius)`` pieces."""
        heads, lengths = [], []
        h = 0.0
        for kind, a, b in segments:
            if kind == "straight":
                n = max(round(a / step), 1)
                heads.append(np.full(n, h))
            else:
                arc = np.radians(abs(a)) * b
                n = max(round(arc / step), 1)
                heads.append(h + np.radians(a) * (np.arange(n) + 0.5) / n)
                h += np.radians(a)
            lengths.append(n)
        heading = np.concatenate(heads)
        xy = np.concatenate([[[0.0, 0.0]], np.cumsum(step * np.stack([np.cos(heading), np.sin(heading)], 1), 0)])
        heading = np.concatenate([heading, heading[-1:]])
        s = np.arange(len(xy)) * step
        z = z_amp * np.sin(s / z_wave) + 0.3 * np.sin(s / 23.0)
        return cls(xy, heading, z, step)

    @property
    def length(self) -> float:
        return (len(self.xy) - 1) * self.step

    def at(self, s: np.ndarray, d: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World xy, heading and centreline height at arc length ``s`` and lateral offset ``d``
        (positive to the left)."""
        s = np.clip(np.asarray(s, float), 0, self.length)
        x = s / self.step
        i = np.minimum(x.astype(int), len(self.xy) - 2)
        f = x - i
        xy = self.xy[i] * (1 - f)[..., None] + self.xy[i + 1] * f[..., None]
        hd = np.unwrap(self.heading)
        heading = hd[i] * (1 - f) + hd[i + 1] * f
        z = self.z[i] * (1 - f) + self.z[i + 1] * f
        normal = np.stack([-np.sin(heading), np.cos(heading)], -1)
        return xy + normal * np.asarray(d, float)[..., None], heading, z


@dataclass
class UrbanParams:
    """Dimensions of the street (metres)."""

    road_half_width: float = 5.0
    camber: float = 0.004  # z = -camber * d^2 across the road
    roughness: float = 0.012  # std of the road's small-scale relief
    curb_height: tuple[float, float] = (0.10, 0.15)
    curb_section: float = 10.0  # curbs are instances of this length (the objects curb detection counts)
    sidewalk_width: float = 3.0
    building_height: tuple[float, float] = (6.0, 22.0)
    car_gap: tuple[float, float] = (1.0, 14.0)
    segments: list[tuple[str, float, float]] = field(
        default_factory=lambda: [
            ("straight", 110.0, 0.0),
            ("turn", 90.0, 35.0),
            ("straight", 90.0, 0.0),
            ("turn", -60.0, 45.0),
            ("straight", 130.0, 0.0),
            ("turn", 40.0, 60.0),
            ("straight", 120.0, 0.0),
        ]
    )


@dataclass
class Scene:
    """A mesh with its generator's metadata."""

    mesh: Mesh
    kind: str
    seed: int
    centerline: Centerline | None = None
    info: dict = field(default_factory=dict)

    def road_height(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Surface height of the road at (s, d) without roughness (for trajectories)."""
        _, _, z = self.centerline.at(s, d)
        return z - self.info.get("camber", 0.0) * np.asarray(d) ** 2


def urban_street(seed: int = 0, params: UrbanParams | None = None) -> Scene:
    """An urban street: cambered, sloped, rough road; curbs 10-15 cm; sidewalks; facades with
    recesses and windows; parked cars with glass; poles, lamps, signs; street trees; hedges."""
    p = params or UrbanParams()
    rng = np.random.default_rng(seed)
    cl = Centerline.from_segments(p.segments)
    b = MeshBuilder()
    W, Ws = p.road_half_width, p.sidewalk_width
    s_grid = np.arange(0, cl.length + 1e-9, 0.5)
    curb_step, curb_sections = max(round(p.curb_section / 0.5), 1), 0

    # road surface with camber, slope (centreline height) and roughness
    d_road = np.linspace(-W, W, 41)
    S, D = np.meshgrid(s_grid, d_road, indexing="ij")
    xy, _, z = cl.at(S, D)
    zr = z - p.camber * D**2 + rng.normal(0, p.roughness, S.shape)
    zr += 0.02 * np.sin(S / 3.1 + rng.uniform(0, 6)) * np.cos(D / 1.7)
    b.grid(np.dstack([xy, zr]), L.GROUND, reflectivity=0.25)

    curb_h = {side: rng.uniform(*p.curb_height) for side in (-1, 1)}
    for side in (-1, 1):
        edge_z = z[:, 0] - p.camber * W**2 if side < 0 else z[:, -1] - p.camber * W**2
        h = curb_h[side]
        # curb face: vertical strip at d = side*W, one instance per curb_section metres
        xy_c, _, _ = cl.at(s_grid, side * W)
        face = np.stack([np.column_stack([xy_c, edge_z - 0.02]), np.column_stack([xy_c, edge_z + h])], axis=1)
        for i in range(0, len(s_grid) - 1, curb_step):
            b.grid(face[i : i + curb_step + 1], L.CURB, reflectivity=0.4, instance=b.new_instance())
            curb_sections += 1
        # sidewalk, slightly sloped towards the road
        d_sw = side * np.linspace(W, W + Ws, 7)
        S2, D2 = np.meshgrid(s_grid, d_sw, indexing="ij")
        xy2, _, z2 = cl.at(S2, D2)
        zs = z2 - p.camber * W**2 + h + 0.02 * (np.abs(D2) - W) + rng.normal(0, 0.004, S2.shape)
        b.grid(np.dstack([xy2, zs]), L.GROUND, reflectivity=0.35)
        # yards / terrain behind the sidewalk up to 25 m
        d_out = side * np.linspace(W + Ws, 25.0, 12)
        S3, D3 = np.meshgrid(s_grid[::4], d_out, indexing="ij")
        xy3, _, z3 = cl.at(S3, D3)
        zt = z3 - p.camber * W**2 + h + 0.06 + 0.3 * np.sin(S3 / 11.0) * np.clip(np.abs(D3) - W - Ws, 0, 2) / 2
        zt += rng.normal(0, 0.03, S3.shape) * (np.abs(D3) > W + Ws + 0.5)
        b.grid(np.dstack([xy3, zt]), L.GROUND, reflectivity=0.3)

    counts = {
        "buildings": 0,
        "cars": 0,
        "poles": 0,
        "trees": 0,
        "bushes": 0,
        "curbs": 2,
        "curb_sections": curb_sections,
    }
    for side in (-1, 1):
        base_h = curb_h[side]
        # buildings
        s = rng.uniform(0, 6)
        while s < cl.length - 8:
            length = rng.uniform(10, 28)
            if s + length > cl.length:
                break
            setback = rng.uniform(0.0, 3.0)
            mid = s + length / 2
            (cx, cy), heading, zc = (
                v[0] if np.ndim(v) else v for v in cl.at(np.array([mid]), side * (W + Ws + setback))
            )
            ground_z = float(zc - p.camber * W**2 + base_h)
            _building(
                b, rng, np.array([cx, cy, ground_z]), float(heading), side, length, rng.uniform(*p.building_height)
            )
            counts["buildings"] += 1
            if setback > 1.3:  # a hedge in the front yard
                (hx, hy), _, _ = (v[0] if np.ndim(v) else v for v in cl.at(np.array([mid]), side * (W + Ws + 0.6)))
                inst = b.new_instance()
                c, sn = np.cos(heading), np.sin(heading)
                for u in np.linspace(-length / 2 + 1, length / 2 - 1, max(int(length / 2.5), 1)):
                    b.leaf_cloud(
                        rng,
                        [hx + c * u, hy + sn * u, ground_z + 0.6],
                        [1.3, 0.45, 0.6],
                        380,
                        0.07,
                        L.VEGETATION,
                        instance=inst,
                        reflectivity=0.45,
                    )
                counts["bushes"] += 1
            gap = rng.uniform(0.0, 12.0)
            for u in np.arange(s + length + 2.5, s + length + gap - 2.0, 5.0):  # trees between buildings
                (tx, ty), _, tz = (v[0] for v in cl.at(np.array([u]), side * (W + Ws + rng.uniform(3.0, 9.0))))
                _tree(b, rng, np.array([tx, ty, float(tz - p.camber * W**2 + base_h)]))
                counts["trees"] += 1
            s += length + gap
        # parked cars along the curb
        s = rng.uniform(3, 15)
        while s < cl.length - 5:
            if rng.random() < 0.45:
                (cx, cy), heading, zc = (v[0] for v in cl.at(np.array([s]), side * (W - 1.15)))
                zc = float(zc - p.camber * (W - 1.15) ** 2)
                _car(b, rng, np.array([cx, cy, zc]), float(heading) + (np.pi if rng.random() < 0.5 else 0.0))
                counts["cars"] += 1
            s += 4.6 + rng.uniform(*p.car_gap)
        # poles with lamps or signs, trees and hedges on the sidewalk
        s = rng.uniform(5, 20)
        while s < cl.length - 3:
            kind = rng.choice(["lamp", "sign", "tree", "tree", "tree", "hedge"])
            d = side * (W + 0.6 if kind in ("lamp", "sign") else W + rng.uniform(1.3, 2.2))
            (cx, cy), heading, zc = (v[0] for v in cl.at(np.array([s]), d))
            zg = float(zc - p.camber * W**2 + base_h)
            if kind in ("lamp", "sign"):
                _pole(b, rng, np.array([cx, cy, zg]), float(heading), side, kind)
                counts["poles"] += 1
            elif kind == "tree":
                _tree(b, rng, np.array([cx, cy, zg]))
                counts["trees"] += 1
            else:
                inst = b.new_instance()
                b.leaf_cloud(
                    rng, [cx, cy, zg + 0.6], [1.6, 0.5, 0.6], 700, 0.07, L.VEGETATION, instance=inst, reflectivity=0.45
                )
                counts["bushes"] += 1
            s += rng.uniform(6, 14)
    return Scene(b.build(), "urban", seed, cl, {"camber": p.camber, **counts})


def _building(b: MeshBuilder, rng, base: np.ndarray, heading: float, side: int, length: float, height: float) -> None:
    """A building whose front facade faces the street: strips of 3 m with recesses, floors of
    3 m with glass windows (the interior walls of the box give returns through the glass)."""
    inst = b.new_instance()
    depth = 12.0
    toward = -side  # facade normal points to the road (towards d = 0)
    c, s = np.cos(heading), np.sin(heading)
    t = np.array([c, s, 0.0])  # along the street
    n = np.array([-s, c, 0.0]) * toward  # out of the facade, towards the street
    up = np.array([0.0, 0.0, 1.0])
    centre = base - n * depth / 2
    b.box(
        centre - up * 0.5,
        (length, depth, height + 0.5),
        heading,
        L.BUILDING,
        instance=inst,
        faces=("+x", "-x", "top", "+y" if toward < 0 else "-y"),
        reflectivity=0.5,
    )
    n_strips = max(int(length // 3), 1)
    w = length / n_strips
    floors = max(int(height // 3), 1)
    fh = height / floors
    for k in range(n_strips):
        recess = 0.4 if rng.random() < 0.25 else 0.0
        x0 = -length / 2 + k * w
        o = base + t * x0 - n * recess - up * 0.5

        def P(u, v, o=o):
            return o + t * u + up * v

        # side faces of a recess
        if recess:
            for u in (0.0, w):
                b.quad(
                    o + t * u,
                    o + t * u + n * recess,
                    o + t * u + n * recess + up * (height + 0.5),
                    o + t * u + up * (height + 0.5),
                    L.BUILDING,
                    instance=inst,
                )
        b.quad(P(0, 0), P(w, 0), P(w, 0.5 + fh), P(0, 0.5 + fh), L.BUILDING, instance=inst)  # ground floor
        for f in range(1, floors):
            v0 = 0.5 + f * fh
            wl, wr, wb, wt = w / 2 - 0.7, w / 2 + 0.7, v0 + 0.9, v0 + 2.5
            for q in ((0, v0, w, wb), (0, wt, w, v0 + fh), (0, wb, wl, wt), (wr, wb, w, wt)):
                b.quad(P(q[0], q[1]), P(q[2], q[1]), P(q[2], q[3]), P(q[0], q[3]), L.BUILDING, instance=inst)
            b.quad(
                P(wl, wb), P(wr, wb), P(wr, wt), P(wl, wt), L.BUILDING, instance=inst, material=GLASS, reflectivity=0.1
            )


def _car(b: MeshBuilder, rng, base: np.ndarray, heading: float) -> None:
    """A parked car: a rounded side profile extruded over the width, glass greenhouse,
    an interior (seats) behind the glass, and four wheels."""
    inst = b.new_instance()
    length, width = rng.uniform(3.9, 4.8), rng.uniform(1.7, 1.9)
    hl = length / 2
    # side profile (x along the car, z up), counter-clockwise, rounded corners
    prof = np.array(
        [
            [-hl, 0.30],
            [-hl + 0.05, 0.55],
            [-hl + 0.15, 0.85],
            [-hl + 0.6, 0.95],
            [-hl + 0.9, 1.40],
            [-hl + 1.2, 1.48],
            [hl - 1.6, 1.48],
            [hl - 1.3, 1.38],
            [hl - 0.9, 1.0],
            [hl - 0.2, 0.9],
            [hl - 0.05, 0.7],
            [hl, 0.45],
            [hl - 0.1, 0.30],
        ]
    )
    c, s = np.cos(heading), np.sin(heading)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    def world(x, y, z):
        return np.stack([x, y, z], -1) @ rot.T + base

    half = width / 2
    m = len(prof)
    # body surface between the two side profiles, quad per profile edge
    for i in range(m):
        j = (i + 1) % m
        a, bb = prof[i], prof[j]
        quad = world(
            np.array([a[0], bb[0], bb[0], a[0]]),
            np.array([-half, -half, half, half]) * 0.92,
            np.array([a[1], bb[1], bb[1], a[1]]),
        )
        glass = (i in (3, 7)) or (i == 4 and False)
        b.add(quad, [[0, 1, 2], [0, 2, 3]], L.VEHICLE, inst, GLASS if glass else 0, 0.1 if glass else 0.6)
    # side walls: lower body solid, greenhouse glass
    centre = prof.mean(axis=0)
    for y in (-half, half):
        lower = prof[prof[:, 1] <= 0.96]
        upper = np.array([prof[3], prof[4], prof[5], prof[6], prof[7], prof[8]])
        for poly, mat in ((lower, 0), (upper, GLASS)):
            pc = poly.mean(axis=0) if mat == GLASS else centre * [1, 0] + [0, 0.62]
            v = np.vstack([pc, poly])
            k = len(poly)
            tris = np.array([[0, 1 + i, 1 + (i + 1) % k] for i in range(k)])
            b.add(world(v[:, 0], np.full(len(v), y), v[:, 1]), tris, L.VEHICLE, inst, mat, 0.1 if mat == GLASS else 0.6)
    # interior behind the glass: seats and dashboard
    b.box(
        world(np.array(0.0), np.array(0.0), np.array(0.5)),
        (1.8, width * 0.7, 0.55),
        heading,
        L.VEHICLE,
        instance=inst,
        reflectivity=0.3,
    )
    for x in (-hl + 0.75, hl - 0.8):
        for y in (-half + 0.02, half - 0.02):
            b.cylinder(
                world(np.array(x), np.array(y), np.array(0.33)),
                rot @ [0, np.sign(y), 0],
                0.33,
                0.2,
                L.VEHICLE,
                segments=14,
                instance=inst,
                material=DARK,
                reflectivity=0.05,
            )


def _pole(b: MeshBuilder, rng, base: np.ndarray, heading: float, side: int, kind: str) -> None:
    inst = b.new_instance()
    h = rng.uniform(5.0, 8.0) if kind == "lamp" else rng.uniform(2.6, 3.2)
    r = rng.uniform(0.06, 0.11)
    b.cylinder(base, [0, 0, 1], r, h, L.POLE, segments=10, instance=inst, reflectivity=0.5)
    toward = -side * np.array([-np.sin(heading), np.cos(heading), 0.0])
    if kind == "lamp":
        arm = base + np.array([0.0, 0.0, h])
        b.cylinder(arm, toward, 0.04, 1.6, L.POLE, segments=6, instance=inst)
        b.box(arm + toward * 1.6 - [0, 0, 0.15], (0.5, 0.25, 0.15), heading, L.POLE, instance=inst)
    else:
        b.box(
            base + np.array([0.0, 0.0, h - 0.7]),
            (0.7, 0.04, 0.7),
            heading + np.pi / 2 * rng.integers(0, 2),
            L.POLE,
            instance=inst,
            reflectivity=0.9,
        )


def _tree(b: MeshBuilder, rng, base: np.ndarray) -> None:
    inst = b.new_instance()
    trunk_h = rng.uniform(2.2, 3.5)
    r = rng.uniform(0.12, 0.25)
    lean = rng.normal(0, 0.05, 3) * [1, 1, 0] + [0, 0, 1]
    b.cylinder(base - [0, 0, 0.1], lean, r, trunk_h + 1.5, L.TRUNK, segments=12, instance=inst, reflectivity=0.35)
    crown_r = rng.uniform(1.8, 3.2)
    top = base + lean / np.linalg.norm(lean) * (trunk_h + crown_r * 0.8)
    b.leaf_cloud(
        rng,
        top,
        [crown_r, crown_r, crown_r * 0.85],
        int(500 * crown_r**2),
        0.1,
        L.VEGETATION,
        instance=inst,
        reflectivity=0.45,
    )


@dataclass
class ForestParams:
    """Forest plot dimensions: a strip ``length x width`` along a winding walking path."""

    length: float = 260.0
    width: float = 60.0
    stems_per_ha: float = 650.0
    relief: float = 2.5
    dbh: tuple[float, float] = (0.15, 0.60)
    path_clearance: float = 1.2


def forest_plot(seed: int = 0, params: ForestParams | None = None) -> Scene:
    """Uneven terrain (metres of relief), leaning stems with a realistic DBH spread, branches,
    understory shrubs and a porous canopy; a walking path winds through it (the centreline)."""
    p = params or ForestParams()
    rng = np.random.default_rng(seed)
    b = MeshBuilder()
    # terrain: a few random Fourier modes with ``relief`` metres peak-to-peak, plus roughness
    modes = [(rng.uniform(0.01, 0.06), rng.uniform(0.01, 0.06), rng.uniform(0, 2 * np.pi)) for _ in range(6)]

    def terrain(x, y):
        z = sum(np.sin(kx * x + ky * y + ph) for kx, ky, ph in modes) * p.relief / 6
        return z + 0.05 * np.sin(x * 0.9) * np.cos(y * 1.3)

    xs = np.arange(-10, p.length + 10.01, 1.0)
    ys = np.arange(-p.width / 2, p.width / 2 + 0.01, 1.0)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    Z = terrain(X, Y) + rng.normal(0, 0.03, X.shape)
    b.grid(np.dstack([X, Y, Z]), L.GROUND, reflectivity=0.3)
    # walking path: a gentle meander through the strip
    path_x = np.arange(0, p.length + 0.01, 0.5)
    amp, wave = rng.uniform(4, 8), rng.uniform(40, 70)
    path_y = amp * np.sin(path_x / wave * 2 * np.pi)
    heading = np.arctan2(np.gradient(path_y), np.gradient(path_x))
    cl = Centerline(np.stack([path_x, path_y], 1), heading, terrain(path_x, path_y), 0.5)
    # stems: Poisson placement, cleared along the path
    area_ha = (p.length + 20) * p.width / 1e4
    n = rng.poisson(p.stems_per_ha * area_ha)
    sx = rng.uniform(-10, p.length + 10, n)
    sy = rng.uniform(-p.width / 2 + 1, p.width / 2 - 1, n)
    dist = np.abs(sy - amp * np.sin(sx / wave * 2 * np.pi))
    keep = dist > p.path_clearance + 0.5
    sx, sy = sx[keep], sy[keep]
    dbh = np.clip(rng.lognormal(np.log(0.28), 0.35, len(sx)), *p.dbh)
    for x, y, d in zip(sx, sy, dbh, strict=True):
        inst = b.new_instance()
        z0 = terrain(x, y)
        height = np.clip(1.3 + 45 * d + rng.normal(0, 2), 8, 32)
        lean = np.array([*rng.normal(0, 0.08, 2), 1.0])
        lean /= np.linalg.norm(lean)
        base = np.array([x, y, z0 - 0.2])
        b.cylinder(base, lean, d / 2, height, L.TRUNK, segments=12, cap=False, instance=inst, reflectivity=0.35)
        crown_base = height * rng.uniform(0.45, 0.65)
        for _ in range(rng.integers(2, 6)):  # branches below and in the crown
            hb = rng.uniform(crown_base * 0.6, height * 0.9)
            az = rng.uniform(0, 2 * np.pi)
            direction = np.array([np.cos(az), np.sin(az), rng.uniform(0.1, 0.6)])
            b.cylinder(
                base + lean * hb,
                direction,
                max(d / 8, 0.02),
                rng.uniform(1.0, 3.0),
                L.VEGETATION,
                segments=5,
                cap=False,
                instance=inst,
            )
        crown_r = rng.uniform(1.5, 3.0)
        centre = base + lean * (crown_base + (height - crown_base) / 2)
        b.leaf_cloud(
            rng,
            centre,
            [crown_r, crown_r, (height - crown_base) / 2],
            int(180 * crown_r**2),
            0.1,
            L.VEGETATION,
            instance=inst,
            reflectivity=0.4,
        )
    # understory shrubs, also kept off the path
    m = rng.poisson(300 * area_ha)
    ux = rng.uniform(-10, p.length + 10, m)
    uy = rng.uniform(-p.width / 2, p.width / 2, m)
    ok = np.abs(uy - amp * np.sin(ux / wave * 2 * np.pi)) > p.path_clearance + 0.8
    for x, y in zip(ux[ok], uy[ok], strict=True):
        r = rng.uniform(0.4, 1.2)
        b.leaf_cloud(
            rng,
            [x, y, terrain(x, y) + r * 0.7],
            [r, r, r * 0.8],
            int(120 * r**2),
            0.06,
            L.VEGETATION,
            instance=b.new_instance(),
            reflectivity=0.4,
        )
    return Scene(
        b.build(),
        "forest",
        seed,
        cl,
        {
            "stems": len(sx),
            "stems_per_ha": len(sx) / area_ha,
            "dbh_mean": float(dbh.mean()),
            "terrain_modes": modes,
        },
    )
