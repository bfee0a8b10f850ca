"""Union-find over the integers ``0..n - 1`` (``parent = np.arange(n)``): the connected components of
voxel grids, range-image segments and segment graphs. Roots are found with path halving; a union
keeps the smaller root, so every component's root is its smallest node."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def find(parent, a):
    """The root of ``a`` (halving the path on the way)."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True, nogil=True)
def union(parent, a, b):
    """Join the components of ``a`` and ``b`` under the smaller of their roots."""
    ra = find(parent, a)
    rb = find(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@njit(cache=True, nogil=True)
def component_ids(parent):
    """Component id of every node: ``0, 1, ...`` in the order of each component's first node."""
    n = parent.shape[0]
    comp = np.empty(n, np.int64)
    ids = np.full(n, -1, np.int64)
    nc = 0
    for v in range(n):
        r = find(parent, v)
        if ids[r] < 0:
            ids[r] = nc
            nc += 1
        comp[v] = ids[r]
    return comp
