"""Rows from a ring / channel / laser-id field (any numbering).

The ids are put in rows by their rings' median elevation, top beam first, on the first sweep;
later sweeps keep that table while their rings stay at their rows' elevations (a driver that
renumbers its rings between sweeps would otherwise scramble the rows without a word).
"""

from __future__ import annotations

import numpy as np

from data_tools.errors import DataError


class RingField:
    """The ring ids of a sequence in row order, and every point's row from its id.

    Attributes
    ----------
    ids : ndarray or None
        The ring field's values in row order (top beam first), from the first sweep.
    """

    def __init__(self) -> None:
        self.ids: np.ndarray | None = None

    def rows(
        self,
        ring: np.ndarray,
        ok: np.ndarray,
        te: np.ndarray,
        beam_te: np.ndarray | None,
        source: str,
        warnings: list[str],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Row of every point (-1 for no-return points) and the beam table (tangents of the
        elevations, top first): ``beam_te`` as given, or rebuilt from this sweep's rings when it is
        the first, holds ids not seen before, or its rings are no longer at their rows' elevations
        (each said in ``warnings``)."""
        if not np.issubdtype(ring.dtype, np.integer):
            if not np.isfinite(ring[ok]).all() or (ring[ok] != np.round(ring[ok])).any():
                raise DataError(f"{source}: the ring field holds non-integer values")
            ring = ring.astype(np.int64)
        ids, inv = np.unique(ring[ok], return_inverse=True)
        if self.ids is not None and not np.isin(ids, self.ids).all():
            new = ~np.isin(ids, self.ids)
            warnings.append(f"{source}: ring ids {ids[new].tolist()[:8]} not seen before; beam table rebuilt")
            self.ids = None
        if self.ids is None:
            beam_te = self._table(ids, inv, ok, te)
            return self._rows(ring, ok), beam_te
        row = self._rows(ring, ok)
        if not rings_at_their_elevations(row, ok, te, beam_te):
            warnings.append(
                f"{source}: the ring ids are no longer at the elevations of the first sweep's (renumbered?); "
                "beam table rebuilt from this sweep"
            )
            beam_te = self._table(ids, inv, ok, te)
            row = self._rows(ring, ok)
        return row, beam_te

    def _table(self, ids: np.ndarray, inv: np.ndarray, ok: np.ndarray, te: np.ndarray) -> np.ndarray:
        """Sets the ring ids in row order (top beam first); returns the beam table, from the rings'
        median elevations."""
        med = np.array([np.median(te[ok][inv == k]) for k in range(len(ids))])  # once per sequence
        self.ids = ids[np.argsort(-med, kind="stable")]
        return np.sort(med)[::-1]

    def _rows(self, ring: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Row of every point from its ring id (-1 for no-return points)."""
        order = np.argsort(self.ids)
        row = np.full(len(ok), -1, np.int64)
        row[ok] = order[np.searchsorted(self.ids[order], ring[ok])]
        return row


def rings_at_their_elevations(
    row: np.ndarray, ok: np.ndarray, te: np.ndarray, beam_te: np.ndarray, every: int = 16
) -> bool:
    """Whether the rings of a sweep (rows from the ring field) still lie at their rows' beam
    elevations: the median elevation of every ``every``-th return per row within half the
    gap to the neighbouring beams, for at least three quarters of the rows with 8 samples or
    more (a ring field renumbered between sweeps would silently scramble the rows)."""
    rows = len(beam_te)
    if rows < 2:
        return True
    idx = np.flatnonzero(ok)[::every]
    r, t = row[idx], te[idx]
    sort = np.lexsort((t, r))
    cnt = np.bincount(r, minlength=rows)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    used = cnt >= 8
    if not used.any():
        return True
    med = np.arctan(t[sort][start[used] + cnt[used] // 2])
    beams = np.arctan(beam_te)
    gap = np.abs(np.diff(beams))
    half = 0.5 * np.minimum(np.append(gap, np.inf), np.append(np.inf, gap))
    off = np.abs(med - beams[used]) > half[used]
    return off.sum() <= 0.25 * used.sum()
