"""A parked-car street (``simulate --scene street``): the scene that exercises the online car detector.

Vehicles beside the sensor (the right parking row 2-3 m from a car in the right lane, a walker's
sidewalk 1-2 m from it) and out past 40 m: parallel-parked rows with gaps on both sides, a section
of angled parking, cars parked askew and off the curb, a car in a driveway half hidden behind the
row, sedans, SUVs, vans and one box truck, and cars driving in both directions (their triangles move
between sweeps: :meth:`StreetScene.move`). Buildings, trees, hedges, poles, curbs and sidewalks as in
:func:`~data_tools.sim.scenes.urban_street`. Every vehicle is one instance of class vehicle (the
ground truth the per-instance scores count).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from data_tools.sim.mesh import DARK, GLASS, MeshBuilder
from data_tools.sim.scenes import Centerline, Scene, _building, _car, _pole, _tree
from prc_slam import labels as L

#: vehicle kinds and their weights in the parked rows
KINDS = ("car", "suv", "van", "car", "suv", "car")


@dataclass
class StreetParams:
    """Dimensions of the street (metres)."""

    right_width: float = 6.5  # centreline to the right curb (a lane and a parking lane)
    left_width: float = 8.5  # centreline to the left curb (a lane and a bay for angled parking)
    camber: float = 0.003
    roughness: float = 0.01
    curb_height: tuple[float, float] = (0.10, 0.15)
    curb_section: float = 10.0
    sidewalk_width: float = 3.0
    building_height: tuple[float, float] = (6.0, 18.0)
    gap: tuple[float, float] = (0.6, 9.0)  # between parked vehicles
    empty: float = 0.2  # chance that a parking place stays empty (the rows' gaps)
    movers: int = 4  # cars driving on the street
    segments: list[tuple[str, float, float]] = field(
        default_factory=lambda: [("straight", 90.0, 0.0), ("turn", 25.0, 80.0), ("straight", 140.0, 0.0)]
    )


@dataclass
class Mover:
    """A vehicle driving along the centreline at lateral offset ``d``: its triangles were built at arc
    length ``s0``; at time ``t`` it is at ``s0 + direction * speed * t``."""

    instance: int
    s0: float
    d: float
    speed: float
    direction: int


@dataclass
class StreetScene(Scene):
    """The street's mesh with the vehicles that drive in it."""

    movers: list[Mover] = field(default_factory=list)

    def moving_triangles(self) -> np.ndarray:
        """Triangles (bool per triangle) of the driving vehicles."""
        return np.isin(self.mesh.instance, [m.instance for m in self.movers]) & (self.mesh.label == L.VEHICLE)

    def move(self, vertices: np.ndarray, t: float) -> np.ndarray:
        """``vertices`` (the mesh's, float64) with every driving vehicle moved to time ``t`` (s): each
        keeps its pose relative to the centreline (turned with it), heading and height included."""
        out = vertices.copy()
        tri = self.mesh.triangles
        for m in self.movers:
            vids = np.unique(tri[(self.mesh.instance == m.instance) & (self.mesh.label == L.VEHICLE)])
            s1 = float(np.clip(m.s0 + m.direction * m.speed * t, 0.0, self.centerline.length))
            (x0, y0), h0, z0 = (v[0] for v in self.centerline.at(np.array([m.s0]), m.d))
            (x1, y1), h1, z1 = (v[0] for v in self.centerline.at(np.array([s1]), m.d))
            c, s = np.cos(h1 - h0), np.sin(h1 - h0)
            p = vertices[vids] - [x0, y0, z0]
            out[vids, 0] = x1 + c * p[:, 0] - s * p[:, 1]
            out[vids, 1] = y1 + s * p[:, 0] + c * p[:, 1]
            out[vids, 2] = z1 + p[:, 2]
        return out


def _clip(poly: np.ndarray, z: float, above: bool) -> np.ndarray:
    """The part of polygon ``poly`` (x, z rows) above (or below) the line ``z`` (Sutherland-Hodgman)."""
    out = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        ina, inb = (a[1] >= z) == above, (b[1] >= z) == above
        if ina:
            out.append(a)
        if ina != inb:
            f = (z - a[1]) / (b[1] - a[1])
            out.append(a + f * (b - a))
    return np.array(out)


def _profile(kind: str, rng: np.random.Generator) -> tuple[np.ndarray, float, float, set[int]]:
    """Side profile (x along the vehicle, z up, counter-clockwise), width, belt line (glass above it
    on the sides; vans and trucks have windows only in the cab) and the glazed profile edges."""
    if kind == "suv":
        hl, w, h = rng.uniform(4.4, 4.9) / 2, rng.uniform(1.85, 2.0), rng.uniform(1.65, 1.85)
        prof = [[-hl, 0.35], [-hl + 0.05, 0.75], [-hl + 0.2, 1.0], [-hl + 0.9, 1.1], [-hl + 1.5, h - 0.05],
                [-hl + 1.7, h], [hl - 0.25, h], [hl - 0.15, h - 0.1], [hl - 0.05, 1.05], [hl, 0.6],
                [hl - 0.1, 0.35]]  # fmt: skip
        return np.array(prof), w, 1.08, {3, 7}
    if kind == "van":
        hl, w, h = rng.uniform(4.9, 5.8) / 2, rng.uniform(1.95, 2.05), rng.uniform(1.95, 2.4)
        prof = [[-hl, 0.35], [-hl + 0.05, 0.8], [-hl + 0.3, 1.05], [-hl + 0.6, 1.15], [-hl + 1.2, h - 0.1],
                [-hl + 1.4, h], [hl - 0.05, h], [hl, h - 0.1], [hl, 0.35]]  # fmt: skip
        return np.array(prof), w, np.inf, {3}
    if kind == "truck":
        hl, w, h = rng.uniform(6.8, 7.8) / 2, 2.4, rng.uniform(3.0, 3.3)
        prof = [[-hl, 0.45], [-hl, 1.3], [-hl + 0.15, 2.4], [-hl + 1.8, 2.55], [-hl + 1.9, h], [hl, h], [hl, 0.6]]
        return np.array(prof), w, np.inf, {1}
    raise ValueError(f"unknown vehicle kind {kind!r}")


def vehicle(b: MeshBuilder, rng: np.random.Generator, base: np.ndarray, heading: float, kind: str) -> int:
    """One vehicle of ``kind`` (``car`` as :func:`~data_tools.sim.scenes._car`, ``suv``, ``van``, ``truck``)
    standing at ``base`` (ground level, centre) facing ``heading``; returns its instance id."""
    if kind == "car":
        inst = b.next_instance
        _car(b, rng, base, heading)
        return inst
    inst = b.new_instance()
    prof, width, belt, glazed = _profile(kind, rng)
    c, s = np.cos(heading), np.sin(heading)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    def world(x, y, z):
        return np.stack([np.broadcast_to(x, np.shape(z)), y, z], -1) @ rot.T + base

    half = width / 2
    m = len(prof)
    for i in range(m):  # the body between the two side profiles
        a, q = prof[i], prof[(i + 1) % m]
        quad = world(np.array([a[0], q[0], q[0], a[0]]), np.array([-half, -half, half, half]),
                     np.array([a[1], q[1], q[1], a[1]]))  # fmt: skip
        glass = i in glazed
        b.add(quad, [[0, 1, 2], [0, 2, 3]], L.VEHICLE, inst, GLASS if glass else 0, 0.1 if glass else 0.6)
    for y in (-half, half):  # side walls: solid below the belt line, glass above
        parts = [(prof, 0)]
        if np.isfinite(belt):
            parts = [(_clip(prof, belt, False), 0), (_clip(prof, belt, True), GLASS)]
        for poly, mat in parts:
            if len(poly) < 3:
                continue
            v = np.vstack([poly.mean(axis=0), poly])
            k = len(poly)
            tris = np.array([[0, 1 + i, 1 + (i + 1) % k] for i in range(k)])
            b.add(world(v[:, 0], np.full(len(v), y), v[:, 1]), tris, L.VEHICLE, inst, mat, 0.1 if mat else 0.6)
    b.box(world(np.array(0.0), np.array(0.0), np.array(0.5)), (1.8, width * 0.7, 0.6), heading, L.VEHICLE,
          instance=inst, reflectivity=0.3)  # fmt: skip
    hl = prof[:, 0].max()
    r = 0.36 if kind != "truck" else 0.48
    for x in (-hl + 0.85, hl - 0.9):
        for y in (-half + 0.02, half - 0.02):
            b.cylinder(world(np.array(x), np.array(y), np.array(r)), rot @ [0, np.sign(y), 0], r, 0.22, L.VEHICLE,
                       segments=14, instance=inst, material=DARK, reflectivity=0.05)  # fmt: skip
    return inst


def street_scene(seed: int = 0, params: StreetParams | None = None) -> StreetScene:
    """The parked-car street of the module docstring, from ``seed``."""
    p = params or StreetParams()
    rng = np.random.default_rng(seed + 1000)
    cl = Centerline.from_segments(p.segments, z_amp=0.6, z_wave=120.0)
    b = MeshBuilder()
    s_grid = np.arange(0, cl.length + 1e-9, 0.5)
    widths = {-1: p.right_width, 1: p.left_width}

    def road_z(s, d):
        _, _, z = cl.at(s, d)
        return z - p.camber * np.asarray(d) ** 2

    d_road = np.linspace(-p.right_width, p.left_width, 61)
    S, D = np.meshgrid(s_grid, d_road, indexing="ij")
    xy, _, _ = cl.at(S, D)
    b.grid(np.dstack([xy, road_z(S, D) + rng.normal(0, p.roughness, S.shape)]), L.GROUND, reflectivity=0.25)
    curb_h, sections = {}, 0
    step = max(round(p.curb_section / 0.5), 1)
    for side in (-1, 1):
        W = widths[side]
        h = curb_h[side] = rng.uniform(*p.curb_height)
        xy_c, _, _ = cl.at(s_grid, side * W)
        edge = road_z(s_grid, side * W)
        face = np.stack([np.column_stack([xy_c, edge - 0.02]), np.column_stack([xy_c, edge + h])], axis=1)
        for i in range(0, len(s_grid) - 1, step):
            b.grid(face[i : i + step + 1], L.CURB, reflectivity=0.4, instance=b.new_instance())
            sections += 1
        d_sw = side * np.linspace(W, W + p.sidewalk_width, 7)
        S2, D2 = np.meshgrid(s_grid, d_sw, indexing="ij")
        xy2, _, _ = cl.at(S2, D2)
        zs = road_z(S2, side * W) + h + 0.02 * (np.abs(D2) - W) + rng.normal(0, 0.004, S2.shape)
        b.grid(np.dstack([xy2, zs]), L.GROUND, reflectivity=0.35)
        d_out = side * np.linspace(W + p.sidewalk_width, W + 22.0, 12)
        S3, D3 = np.meshgrid(s_grid[::4], d_out, indexing="ij")
        xy3, _, _ = cl.at(S3, D3)
        zt = road_z(S3, side * W) + h + 0.06 + rng.normal(0, 0.03, S3.shape) * (np.abs(D3) > W + p.sidewalk_width + 0.5)
        b.grid(np.dstack([xy3, zt]), L.GROUND, reflectivity=0.3)

    counts = {"buildings": 0, "cars": 0, "moving_cars": 0, "poles": 0, "trees": 0, "bushes": 0, "curbs": 2,
              "curb_sections": sections, "angled": 0, "occluded": 0, "trucks": 0}  # fmt: skip

    def place(s: float, d: float, yaw: float, kind: str) -> int:
        (x, y), heading, _ = (v[0] for v in cl.at(np.array([s]), d))
        counts["cars"] += 1
        return vehicle(b, rng, np.array([x, y, float(road_z(s, d))]), float(heading) + yaw, kind)

    for side in (-1, 1):
        W, h = widths[side], curb_h[side]
        # buildings with hedges in front yards and trees between them
        s = rng.uniform(0, 6)
        while s < cl.length - 8:
            length = rng.uniform(10, 26)
            if s + length > cl.length:
                break
            setback = rng.uniform(1.0, 6.0)
            mid = s + length / 2
            (cx, cy), heading, _ = (v[0] for v in cl.at(np.array([mid]), side * (W + p.sidewalk_width + setback)))
            gz = float(road_z(mid, side * W)) + h
            _building(b, rng, np.array([cx, cy, gz]), float(heading), side, length, rng.uniform(*p.building_height))
            counts["buildings"] += 1
            if setback > 2.5 and rng.random() < 0.6:  # a hedge along the front yard
                (hx, hy), _, _ = (v[0] for v in cl.at(np.array([mid]), side * (W + p.sidewalk_width + 0.6)))
                inst = b.new_instance()
                for u in np.linspace(-length / 2 + 1, length / 2 - 1, max(int(length / 2.5), 1)):
                    b.leaf_cloud(rng, [hx + np.cos(heading) * u, hy + np.sin(heading) * u, gz + 0.6], [1.3, 0.45, 0.6],
                                 380, 0.07, L.VEGETATION, instance=inst, reflectivity=0.45)  # fmt: skip
                counts["bushes"] += 1
            elif setback > 4.5 and side < 0:  # a car in the front yard, half hidden behind the parked row
                place(mid, side * (W + p.sidewalk_width + 1.2), rng.normal(0, 0.1), "car")
                counts["occluded"] += 1
            gap = rng.uniform(0.0, 10.0)
            for u in np.arange(s + length + 2.5, s + length + gap - 2.0, 5.0):
                (tx, ty), _, _ = (v[0] for v in cl.at(np.array([u]), side * (W + p.sidewalk_width + rng.uniform(2, 8))))
                _tree(b, rng, np.array([tx, ty, float(road_z(u, side * W)) + h]))
                counts["trees"] += 1
            s += length + gap
        # poles, street trees and hedges on the sidewalk
        s = rng.uniform(5, 20)
        while s < cl.length - 3:
            kind = rng.choice(["lamp", "sign", "tree", "tree", "hedge"])
            d = side * (W + 0.6 if kind in ("lamp", "sign") else W + rng.uniform(1.3, 2.2))
            (cx, cy), heading, _ = (v[0] for v in cl.at(np.array([s]), d))
            gz = float(road_z(s, side * W)) + h
            if kind in ("lamp", "sign"):
                _pole(b, rng, np.array([cx, cy, gz]), float(heading), side, kind)
                counts["poles"] += 1
            elif kind == "tree":
                _tree(b, rng, np.array([cx, cy, gz]))
                counts["trees"] += 1
            else:
                b.leaf_cloud(rng, [cx, cy, gz + 0.6], [1.6, 0.5, 0.6], 700, 0.07, L.VEGETATION,
                             instance=b.new_instance(), reflectivity=0.45)  # fmt: skip
                counts["bushes"] += 1
            s += rng.uniform(7, 16)
        # parked vehicles: parallel rows with gaps, askew and off the curb; on the left an angled bay
        angled = (rng.uniform(60, 110), rng.uniform(20, 35)) if side > 0 else (np.inf, 0.0)
        truck_at = rng.uniform(25, 70) if side < 0 else np.inf
        s = rng.uniform(2, 8)
        while s < cl.length - 6:
            if angled[0] <= s < angled[0] + angled[1]:  # angled parking: 45-60 deg, 2.6 m apart
                a = np.radians(rng.uniform(45, 60))
                place(s, side * (W - 2.3), side * a + (np.pi if rng.random() < 0.3 else 0.0), "car")
                counts["angled"] += 1
                s += 2.6 + rng.uniform(0, 0.6)
                continue
            if s >= truck_at:
                place(s + 2.0, side * (W - 1.5), 0.0, "truck")
                counts["trucks"] += 1
                truck_at = np.inf
                s += 8.5 + rng.uniform(*p.gap)
                continue
            kind = str(rng.choice(KINDS))
            length = {"car": 4.4, "suv": 4.7, "van": 5.4}[kind]
            if rng.random() >= p.empty:
                off = rng.uniform(0.2, 0.9)  # from the curb
                yaw = rng.normal(0, np.radians(4)) + (np.pi if rng.random() < 0.5 else 0.0)
                place(s + length / 2, side * (W - 1.0 - off), yaw, kind)
            s += length + rng.uniform(*p.gap)
    # moving vehicles: in the oncoming lane (passing 2-3 m from a car in the right lane) and ahead
    movers = []
    for k in range(p.movers):
        oncoming = k % 2 == 0
        s0 = rng.uniform(30, cl.length - 40) if oncoming else rng.uniform(14, 30)
        d = 1.75 if oncoming else -1.8
        inst = place(s0, d, np.pi if oncoming else 0.0, str(rng.choice(("car", "suv", "car", "van"))))
        speed = rng.uniform(6.0, 11.0) if oncoming else rng.uniform(8.5, 11.0)  # ahead: no slower than the sensor
        movers.append(Mover(inst, s0, d, speed, -1 if oncoming else 1))
        counts["moving_cars"] += 1
    info = {"camber": p.camber, "walk_lateral": -(p.right_width + 1.2), **counts}
    return StreetScene(b.build(), "street", seed, cl, info, movers)
