"""Airborne (ALS-like) tiles over terrain, with per-point truth, drawn analytically.

The ray-cast airborne simulator (:mod:`data_tools.sim.airborne`) flies the urban and forest
scenes, which are nearly flat. Real tiles have terrain: hills and valleys with 10-35 deg slopes,
terraces and embankments, road cuts, river banks, quarry walls, dense canopy on a slope, water
without returns, bridges, large flat roofs beside low ground, tiles whose edge cuts a building.
This module draws such tiles without a mesh: the terrain is a height function ``z = f(x, y)``
(a sum of smooth hills, a slope plane, terrace steps, embankments, cuts and channels), buildings
are boxes (flat or gabled roofs, walls seen sparsely), trees are ellipsoidal crowns with a few
ground returns below them.

Pulses fall on a jittered grid at ``density`` per m^2 (near nadir: the first surface above each
x-y is the first return). A pulse on a crown gives one to ``max_returns - 1`` vegetation returns
(each further one with probability ``foliage_pass``) and reaches the ground with probability
``ground_pass`` (the canopy's gap fraction); a pulse over water gives no return; a few pulses are
outliers (birds, multipath low points). Every return gets Gaussian z noise ``z_sigma``.

Truth per point: ``ground`` (terrain, also its steep walls: ASPRS class 2), ``building``,
``vegetation``, ``unclassified`` for other surfaces (bridge decks: ASPRS 17, not ground) and
``noise`` for the outliers. Same config, same cloud.

The cases (:data:`CASES`) each stress one thing a flat scene does not; ``flat`` is the
reference. All are vectorised numpy: a 100 m x 100 m tile at 10 points/m^2 takes ~0.1 s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from data_tools.sim.airborne import SimCloud
from prc_slam import labels as L

#: the terrain cases, each with its own layout (see :func:`terrain_case`)
CASES = ("flat", "hills", "slope", "terraces", "forest_slope", "cliff", "river", "roofs")


class TerrainConfig(BaseModel):
    """An ALS-like tile over one terrain case (same config, same cloud)."""

    model_config = ConfigDict(extra="forbid")

    case: str = Field("hills", description="one of CASES")
    seed: int = 0
    size: float = Field(100.0, gt=10, description="tile side (m); the tile is [-size/2, size/2)^2")
    density: float | None = Field(None, gt=0, le=200, description="pulses per m^2 (None: the case's own)")
    z_sigma: float = Field(0.04, ge=0, description="Gaussian z noise of every return (m)")
    max_returns: int = Field(4, ge=1, le=15)
    foliage_pass: float = Field(0.5, ge=0, le=1, description="P(one more vegetation return in a crown)")
    ground_pass: float | None = Field(None, ge=0, le=1, description="P(a pulse on a crown reaches the ground)")
    wall_share: float = Field(0.15, ge=0, le=1, description="wall points per m^2 of wall, as a share of density")
    outlier_rate: float = Field(1e-4, ge=0, le=0.1, description="outlier pulses (half high, half low)")


# ---- terrain components: each maps (x, y) to a height change (m), vectorised ----------------


def hill(cx: float, cy: float, height: float, sigma: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A Gaussian hill (a valley when ``height`` < 0); its steepest slope is
    ``height / sigma * exp(-1/2)``."""
    return lambda x, y: height * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))


def plane(gx: float, gy: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A slope plane ``gx * x + gy * y``."""
    return lambda x, y: gx * x + gy * y


def _across(x: np.ndarray, y: np.ndarray, p0: tuple[float, float], angle_deg: float) -> np.ndarray:
    """Signed distance of (x, y) from the line through ``p0`` at ``angle_deg`` (left positive)."""
    a = np.radians(angle_deg)
    return -(x - p0[0]) * np.sin(a) + (y - p0[1]) * np.cos(a)


def steps(
    p0: tuple[float, float], angle_deg: float, height: float, width: float, spacing: float, count: int
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``count`` terrace steps of ``height`` rising to the left of the line through ``p0``, one
    every ``spacing`` m, each riser ``width`` m wide (slope ``height / width``)."""

    def f(x, y):
        d = _across(x, y, p0, angle_deg)
        z = np.zeros(np.shape(d))
        for k in range(count):
            z = z + height * np.clip((d - k * spacing) / width + 0.5, 0.0, 1.0)
        return z

    return f


def embankment(
    p0: tuple[float, float], angle_deg: float, height: float, crest: float, side_slope: float
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A ridge of ``height`` along the line: a flat crest ``crest`` m wide, sides at ``side_slope``
    (rise per m), added to the terrain."""

    def f(x, y):
        d = np.abs(_across(x, y, p0, angle_deg))
        return np.minimum(height, np.maximum(0.0, (crest / 2 + height / side_slope - d) * side_slope))

    return f


@dataclass
class Cut:
    """A level corridor cut into the terrain (a road cut, a river channel, a pit): inside
    ``half_width`` of the line the surface is at ``level`` (or ``level`` + the terrain's
    ``follow`` share), rising at ``wall_slope`` (rise per m) until it meets the terrain; applied
    as ``min(terrain, cut)``. ``half_length`` (m, from ``p0``) bounds it along the line."""

    p0: tuple[float, float]
    angle_deg: float
    half_width: float
    level: float
    wall_slope: float
    half_length: float = np.inf

    def apply(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        a = np.radians(self.angle_deg)
        along = np.abs((x - self.p0[0]) * np.cos(a) + (y - self.p0[1]) * np.sin(a))
        d = np.abs(_across(x, y, self.p0, self.angle_deg))
        out = np.maximum(d - self.half_width, along - self.half_length)
        return np.minimum(z, self.level + np.maximum(out, 0.0) * self.wall_slope)


@dataclass
class Terrain:
    """``z = sum(components) `` then each cut (``min``); ``water``: (line point, angle, half
    width) of channels whose bottom returns nothing."""

    components: list
    cuts: list[Cut]
    water: list[tuple[tuple[float, float], float, float]]

    def z(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        z = np.zeros(np.shape(x))
        for c in self.components:
            z = z + c(x, y)
        for c in self.cuts:
            z = c.apply(x, y, z)
        return z

    def wet(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        m = np.zeros(np.shape(x), bool)
        for p0, ang, hw in self.water:
            m |= np.abs(_across(x, y, p0, ang)) < hw
        return m


@dataclass
class Building:
    """A box on the terrain: centre, length (along ``angle_deg``), width, height of the eaves
    above the highest terrain under it (on a slope the downhill walls are taller), ``ridge``
    extra height of a gabled roof (0: flat)."""

    cx: float
    cy: float
    length: float
    width: float
    height: float
    angle_deg: float = 0.0
    ridge: float = 0.0

    def local(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = np.radians(self.angle_deg)
        u = (x - self.cx) * np.cos(a) + (y - self.cy) * np.sin(a)
        v = -(x - self.cx) * np.sin(a) + (y - self.cy) * np.cos(a)
        return u, v

    def inside(self, x: np.ndarray, y: np.ndarray, margin: float = 0.0) -> np.ndarray:
        u, v = self.local(x, y)
        return (np.abs(u) < self.length / 2 + margin) & (np.abs(v) < self.width / 2 + margin)

    def eaves(self, terrain: Terrain) -> float:
        """Height of the eaves: ``height`` above the highest terrain under the footprint."""
        u, v = np.meshgrid(np.linspace(-0.5, 0.5, 9) * self.length, np.linspace(-0.5, 0.5, 9) * self.width)
        a = np.radians(self.angle_deg)
        x = self.cx + u * np.cos(a) - v * np.sin(a)
        y = self.cy + u * np.sin(a) + v * np.cos(a)
        return float(terrain.z(x.ravel(), y.ravel()).max()) + self.height

    def roof(self, x: np.ndarray, y: np.ndarray, eaves: float) -> np.ndarray:
        _, v = self.local(x, y)
        return eaves + self.ridge * (1.0 - 2.0 * np.abs(v) / self.width)


@dataclass
class Trees:
    """Crowns on a jittered grid of ``spacing`` m (one tree per cell where ``presence`` says):
    ellipsoids of radius ``radius`` (range) m and half depth ``depth`` (range) m, topped at
    ``height`` (range) m above the terrain at the stem. ``where`` limits them (x, y -> bool)."""

    spacing: float
    presence: float
    radius: tuple[float, float]
    height: tuple[float, float]
    depth: tuple[float, float]
    where: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None


@dataclass
class Case:
    """One terrain case: the terrain, buildings, trees, bridge decks (x0, y0, x1, y1, z) and
    its defaults (pulse density, canopy gap fraction)."""

    terrain: Terrain
    buildings: list[Building]
    trees: Trees | None
    bridges: list[tuple[float, float, float, float, float]]
    density: float
    ground_pass: float


def terrain_case(name: str) -> Case:
    """The layout of case ``name`` on a 100 m tile centred at the origin.

    * ``flat``: nearly level ground (0.3 m swells), three houses (one gabled), street trees;
    * ``hills``: hills and a valley, slopes up to ~30 deg, houses on the gentler parts, trees;
    * ``slope``: a 30 deg hillside with houses cut into it, trees;
    * ``terraces``: 12 % slope with 1.8 m terrace steps (45 deg risers), a 5 m road embankment
      (34 deg sides) and a road cut (1:1) through a hill;
    * ``forest_slope``: closed canopy (15-25 m trees) on a 22-30 deg slope; 15 % of the pulses
      on a crown reach the ground;
    * ``cliff``: a quarry pit 18 m deep with 80 deg walls and a bench, a building on the rim;
    * ``river``: a valley with 25 deg banks, 14 m of water (no returns) and a bridge deck;
    * ``roofs``: a 70 x 45 m flat warehouse roof 9 m above the yard, a sunken loading dock, a
      building cut by the tile's edge, at 2 points/m^2.
    """
    if name == "flat":
        t = Terrain([hill(-20, 10, 0.3, 15), hill(25, -20, -0.3, 12)], [], [])
        b = [Building(-20, -20, 18, 12, 7.0), Building(25, 20, 14, 10, 5.0, 30, ridge=3.0), Building(20, -25, 10, 8, 4)]
        return Case(t, b, Trees(12.0, 0.3, (2.0, 3.5), (6, 12), (1.5, 3.0)), [], 8.0, 0.5)
    if name == "hills":
        t = Terrain([hill(-25, -15, 18, 18), hill(30, 25, 14, 14), hill(10, -35, -8, 12), plane(0.05, 0.02)], [], [])
        b = [Building(-5, 30, 14, 10, 6, 15), Building(38, -20, 12, 9, 5, -20, ridge=2.5)]
        return Case(t, b, Trees(10.0, 0.25, (2.0, 3.5), (8, 16), (2.0, 3.5)), [], 6.0, 0.5)
    if name == "slope":
        t = Terrain([plane(np.tan(np.radians(30)), 0.0), hill(0, 0, 2.0, 15)], [], [])
        b = [Building(-20, 20, 12, 9, 6, 0, ridge=2.0), Building(15, -25, 10, 10, 5)]
        return Case(t, b, Trees(10.0, 0.3, (2.0, 3.5), (8, 16), (2.0, 3.5)), [], 10.0, 0.5)
    if name == "terraces":
        t = Terrain(
            [plane(0.12, 0.0), steps((-40, 0), -90, 1.8, 1.8, 12.0, 5), hill(30, -30, 12, 12),
             embankment((0, -25), 0, 5.0, 8.0, 2 / 3)],
            [Cut((30, -30), 90, 4.0, 12.6, 1.0, 25.0)], [],
        )  # fmt: skip
        b = [Building(-30, 30, 12, 8, 6), Building(10, 30, 10, 8, 5, 0, ridge=2.5)]
        return Case(t, b, Trees(12.0, 0.2, (2.0, 3.0), (6, 12), (1.5, 3.0)), [], 8.0, 0.5)
    if name == "forest_slope":
        t = Terrain([plane(np.tan(np.radians(22)), 0.05), hill(10, 15, 8, 14), hill(-30, -25, -6, 12)], [], [])
        return Case(t, [], Trees(5.0, 1.0, (2.8, 4.2), (15, 25), (3.0, 6.0)), [], 12.0, 0.15)
    if name == "cliff":
        t = Terrain(
            [hill(-30, 35, 3.0, 15), plane(0.02, 0.01)],
            [Cut((5, -5), 0, 16.0, -18.0, np.tan(np.radians(80)), 22.0),
             Cut((5, -5), 0, 24.0, -8.0, np.tan(np.radians(80)), 30.0)], [],
        )  # fmt: skip
        b = [Building(-38, 30, 14, 10, 7), Building(40, 38, 10, 8, 5)]
        return Case(t, b, Trees(12.0, 0.25, (2.0, 3.0), (6, 12), (1.5, 3.0), where=_off_pit), [], 6.0, 0.5)
    if name == "river":
        t = Terrain(
            [plane(0.03, 0.0), hill(-35, 35, 6, 15)],
            [Cut((0, 0), 80, 7.0, -6.0, np.tan(np.radians(25)))],
            [((0, 0), 80, 7.0)],
        )
        bridge = (-30.0, -5.0, 30.0, 3.0, 0.6)  # deck x-y box, its height over the lower bank top
        b = [Building(-35, -35, 16, 10, 6), Building(30, 35, 12, 10, 5, 10, ridge=2.5)]
        trees = Trees(8.0, 0.35, (2.0, 3.5), (8, 14), (2.0, 3.5), where=_bank)
        return Case(t, b, trees, [bridge], 8.0, 0.5)
    if name == "roofs":
        t = Terrain([plane(0.01, 0.0)], [Cut((-5, -23), 0, 4.0, -1.2, 1.0, 14.0)], [])
        b = [Building(-5, 5, 70, 45, 9), Building(40, -38, 30, 22, 7), Building(-47, -35, 26, 14, 6)]
        return Case(t, b, Trees(14.0, 0.15, (2.0, 3.0), (6, 10), (1.5, 2.5)), [], 2.0, 0.5)
    raise ValueError(f"unknown terrain case {name!r}; choose one of {', '.join(CASES)}")


def _off_pit(x, y):
    return ~((np.abs(x - 5) < 36) & (np.abs(y + 5) < 30))


def _bank(x, y):
    d = np.abs(_across(x, y, (0, 0), 80))
    return (d > 8.0) & (d < 30.0)


# ---- sampling ---------------------------------------------------------------------------------


def _pulses(rng: np.random.Generator, size: float, density: float) -> np.ndarray:
    """Jittered grid of pulse footprints over [-size/2, size/2)^2."""
    step = 1.0 / np.sqrt(density)
    c = np.arange(-size / 2, size / 2, step) + step / 2
    x, y = np.meshgrid(c, c, indexing="ij")
    xy = np.column_stack([x.ravel(), y.ravel()]) + rng.uniform(-step / 2.5, step / 2.5, (x.size, 2))
    return xy[(np.abs(xy) < size / 2).all(axis=1)]


def _crowns(tr: Trees, rng: np.random.Generator, size: float, terrain: Terrain, buildings: list[Building]):
    """Tree centres, radii (0: no tree), tops, half depths (arrays) on the jittered grid; and the
    grid's origin, shape and spacing so that a point finds its candidate trees among 3 x 3 cells."""
    n = int(np.ceil(size / tr.spacing)) + 2
    o = -size / 2 - tr.spacing
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    jit = rng.uniform(0.2, 0.8, (n, n, 2)) * tr.spacing
    cx, cy = o + i * tr.spacing + jit[..., 0], o + j * tr.spacing + jit[..., 1]
    r = rng.uniform(*tr.radius, (n, n))
    r = np.minimum(r, tr.spacing)  # a crown reaches its cell's neighbours at most
    top = terrain.z(cx, cy) + rng.uniform(*tr.height, (n, n))
    depth = rng.uniform(*tr.depth, (n, n))
    present = rng.random((n, n)) < tr.presence
    if tr.where is not None:
        present &= tr.where(cx, cy)
    present &= ~terrain.wet(cx, cy)
    for b in buildings:
        present &= ~b.inside(cx, cy, margin=1.0) & ~b.inside(cx, cy, margin=r)
    return cx, cy, np.where(present, r, 0.0), top, depth, o, n, tr.spacing


def _canopy(xy: np.ndarray, crowns) -> tuple[np.ndarray, np.ndarray]:
    """Top and bottom of the highest crown above each x-y (NaN where none)."""
    cx, cy, r, top, depth, o, n, spacing = crowns
    # a point's own cell, then the 3 x 3 around it
    ci = np.clip(((xy[:, 0] - o) / spacing).astype(np.int64), 1, n - 2)
    cj = np.clip(((xy[:, 1] - o) / spacing).astype(np.int64), 1, n - 2)
    best_top = np.full(len(xy), -np.inf)
    best_bot = np.full(len(xy), np.nan)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            a, b = ci + di, cj + dj
            rr = r[a, b]
            d2 = (xy[:, 0] - cx[a, b]) ** 2 + (xy[:, 1] - cy[a, b]) ** 2
            inside = d2 < rr**2
            h = depth[a, b] * np.sqrt(np.clip(1.0 - d2 / np.maximum(rr, 1e-9) ** 2, 0.0, 1.0))
            centre = top[a, b] - depth[a, b]
            t = np.where(inside, centre + h, -np.inf)
            better = t > best_top
            best_top = np.where(better, t, best_top)
            best_bot = np.where(better, centre - h, best_bot)
    best_top[~np.isfinite(best_top)] = np.nan
    return best_top, best_bot


def simulate_terrain(config: TerrainConfig) -> SimCloud:
    """Draw the tile of ``config``.

    Parameters
    ----------
    config : TerrainConfig

    Returns
    -------
    SimCloud
        Points (N, 3) in pulse order (returns of a pulse together, first return first), truth
        ``labels``, ``instance`` (building / tree number + 1, 0 for ground), return numbers,
        ``source`` 0, ``time`` by pulse, ``intensity`` 0; ``meta`` has the case, its density and
        ``region`` (x0, y0, x1, y1).
    """
    cfg = config
    case = terrain_case(cfg.case)
    rng = np.random.default_rng([cfg.seed, CASES.index(cfg.case), 7331])
    density = cfg.density or case.density
    ground_pass = case.ground_pass if cfg.ground_pass is None else cfg.ground_pass
    terrain, buildings = case.terrain, case.buildings
    xy = _pulses(rng, cfg.size, density)
    n = len(xy)
    zt = terrain.z(xy[:, 0], xy[:, 1])
    # the first surface of each pulse: roof, bridge deck, crown or terrain (water: none)
    surface = np.full(n, L.GROUND, np.uint8)
    inst = np.zeros(n, np.uint32)
    z1 = zt.copy()
    for k, b in enumerate(buildings):
        m = b.inside(xy[:, 0], xy[:, 1])
        z1[m] = b.roof(xy[m, 0], xy[m, 1], b.eaves(terrain))
        surface[m], inst[m] = L.BUILDING, k + 1
    for bx0, by0, bx1, by1, over in case.bridges:
        deck = _bank_top(terrain, bx0, by0, bx1, by1) + over
        m = (xy[:, 0] >= bx0) & (xy[:, 0] < bx1) & (xy[:, 1] >= by0) & (xy[:, 1] < by1) & (zt < deck)
        z1[m], surface[m] = deck, L.UNCLASSIFIED
    top = bot = np.full(n, np.nan)
    if case.trees is not None:
        crowns = _crowns(case.trees, rng, cfg.size, terrain, buildings)
        top, bot = _canopy(xy, crowns)
    crown = np.isfinite(top) & (top > z1) & (surface == L.GROUND)
    wet = terrain.wet(xy[:, 0], xy[:, 1]) & (surface == L.GROUND)
    # returns: one from a roof, deck or bare terrain; on a crown 1..max_returns-1 from the
    # foliage (each further with foliage_pass) and the ground with ground_pass
    n_veg = np.where(crown, 1, 0)
    more = crown.copy()
    for _ in range(max(cfg.max_returns - 2, 0)):
        more &= rng.random(n) < cfg.foliage_pass
        n_veg += more
    reach = ~crown | (rng.random(n) < ground_pass)
    last = reach & ~wet  # the surface below (terrain, roof, deck) returns
    if cfg.max_returns == 1:
        last &= ~crown
    nret = n_veg + last
    pulse = np.repeat(np.arange(n), nret)
    first = np.cumsum(nret) - nret
    ret = np.arange(len(pulse)) - first[pulse]  # 0-based return number
    is_veg = ret < n_veg[pulse]
    # foliage returns: the first near the crown top, later ones deeper (sorted downward)
    u = rng.random(len(pulse))
    depth_share = np.where(ret == 0, 0.1 * u, (ret + u) / np.maximum(n_veg[pulse], 1))
    tp, bp = top[pulse], bot[pulse]
    zv = tp - np.clip(depth_share, 0.0, 1.0) * (tp - bp)
    z = np.where(is_veg, zv, z1[pulse])
    lab = np.where(is_veg, L.VEGETATION, surface[pulse]).astype(np.uint8)
    ins = np.where(is_veg, 0, inst[pulse]).astype(np.uint32)
    pts = np.column_stack([xy[pulse], z])
    # walls seen sparsely: wall_share of the density per m^2 of wall, between terrain and eaves
    walls = [_wall_points(b, k, terrain, rng, density * cfg.wall_share) for k, b in enumerate(buildings)]
    # outliers: high (birds) or low (multipath) over random pulses
    n_out = rng.binomial(n, cfg.outlier_rate)
    oxy = xy[rng.integers(0, n, n_out)] if n and n_out else np.zeros((0, 2))
    oz = terrain.z(oxy[:, 0], oxy[:, 1]) + np.where(rng.random(n_out) < 0.5, rng.uniform(15, 60, n_out),
                                                    -rng.uniform(1.5, 8, n_out))  # fmt: skip
    parts = [(pts, lab, ins, ret + 1, nret[pulse])]
    parts += [(w, np.full(len(w), L.BUILDING, np.uint8), np.full(len(w), k + 1, np.uint32), np.ones(len(w), int),
               np.ones(len(w), int)) for k, w in enumerate(walls)]  # fmt: skip
    parts.append((np.column_stack([oxy, oz]), np.full(n_out, L.NOISE, np.uint8), np.zeros(n_out, np.uint32),
                  np.ones(n_out, int), np.ones(n_out, int)))  # fmt: skip
    p, lab, ins, rn, nr = (np.concatenate(c) for c in zip(*parts, strict=True))
    half = cfg.size / 2
    keep = (np.abs(p[:, 0]) < half) & (np.abs(p[:, 1]) < half)
    p, lab, ins, rn, nr = p[keep], lab[keep], ins[keep], rn[keep], nr[keep]
    p[:, 2] += rng.normal(0.0, cfg.z_sigma, len(p))
    m = len(p)
    return SimCloud(
        points=p,
        labels=lab,
        instance=ins,
        return_number=rn.astype(np.uint8),
        number_of_returns=nr.astype(np.uint8),
        source=np.zeros(m, np.uint16),
        time=np.arange(m, dtype=np.float64) * 1e-5,
        intensity=np.zeros(m, np.float32),
        meta={
            "sensor": "als_terrain",
            "config": cfg.model_dump(mode="json"),
            "density": density,
            "ground_pass": ground_pass,
            "region": [-half, -half, half, half],
        },
    )


def _bank_top(terrain: Terrain, x0: float, y0: float, x1: float, y1: float) -> float:
    """Terrain height at the two ends (along x) of a deck: the lower of the two (a level deck)."""
    return float(terrain.z(np.array([x0, x1]), np.array([(y0 + y1) / 2] * 2)).min())


def _wall_points(b: Building, k: int, terrain: Terrain, rng: np.random.Generator, per_m2: float) -> np.ndarray:
    """Points on the four walls of ``b``: uniform along the perimeter, z between the terrain
    and the eaves, ``per_m2`` per square metre of wall."""
    perim = 2 * (b.length + b.width)
    m = int(rng.poisson(max(perim * b.height * per_m2, 0.0)))
    s = rng.random(m) * perim
    hl, hw = b.length / 2, b.width / 2
    corners = np.array([(-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw)])
    at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(corners, axis=0), axis=1))])
    u, v = np.interp(s, at, corners[:, 0]), np.interp(s, at, corners[:, 1])
    a = np.radians(b.angle_deg)
    x = b.cx + u * np.cos(a) - v * np.sin(a)
    y = b.cy + u * np.sin(a) + v * np.cos(a)
    zg = terrain.z(x, y)
    eave = b.eaves(terrain)
    z = zg + rng.random(m) * np.maximum(eave - zg, 0.0)
    return np.column_stack([x, y, z])[eave - zg > 0.3]


def ground_scores(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Ground precision and recall of a ground mask ``pred`` against truth codes (noise and
    other classes count as not ground)."""
    t = truth == L.GROUND
    tp = float(np.count_nonzero(pred & t))
    return tp / max(float(np.count_nonzero(pred)), 1.0), tp / max(float(np.count_nonzero(t)), 1.0)
