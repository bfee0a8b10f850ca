"""The organiser: any sweep of points (any order, any spinning sensor) -> a ``Scan`` range image.

PRC (Lehtola et al. 2019, Sec. III) is defined on the raw stream as a range image whose rows
are scan lines (one beam's sweep for a spinning multi-beam sensor) and whose columns run along
a line. Readers that only have a point cloud call :class:`Organizer` to rebuild that image,
with an exact map from every input point to its slot so that labels computed on the image go
back to every input point, in input order.

Rows (beams) come from, in this order of preference (``method="auto"``):

1. a ring / channel / laser-id field (:mod:`~data_tools.organize.ring_field`);
2. the point order, when it is consistent: ring-major or column-major
   (:mod:`~data_tools.organize.point_order`);
3. clustering of elevation angles into the sensor's beams (:mod:`~data_tools.organize.beams`).

Azimuths and elevations are measured about the sensor's spin axis
(:mod:`~data_tools.organize.spin_axis`); columns come from the azimuth
(:mod:`~data_tools.organize.columns`); every sweep is checked (:mod:`~data_tools.organize.checks`):
out of range -> a warning logged on ``prc_slam.organize`` and counted in ``Scan.meta["organize"]``;
a sweep that cannot be organised -> :class:`DataError` naming the source. A collapse is never silent.

No-return input points (NaN/inf coordinates, or exactly at the origin): they keep their entry
in the input order, are counted (``nonfinite_points``), never reach PRC, and are represented
in the Scan as a zero row of ``Scan.cloud`` mapped to an empty slot (range 0), so
``Scan.per_point`` gives them label 0 (no_return) and ``Scan.points()`` stays finite.
"""

from data_tools.organize.beams import (
    ELEVATION_BINS,
    MIN_BEAM_CONCENTRATION,
    beam_concentration,
    estimate_beam_offset,
    estimate_beams,
)
from data_tools.organize.checks import (
    MAX_COLLISIONS,
    MIN_OCCUPANCY,
    WARN_COLLISIONS,
    OrganizeReport,
    OrganizeSummary,
)
from data_tools.organize.columns import MAX_COLUMNS
from data_tools.organize.organizer import METHODS, Organizer, warm_up
from data_tools.organize.point_order import RING_REUSE_COST
from data_tools.organize.polar import MAX_RANGE, TWO_PI
from data_tools.organize.spin_axis import (
    SPIN_AXIS_MAX_TILT_DEG,
    SPIN_AXIS_MIN_GAIN,
    SPIN_AXIS_MIN_TILT_DEG,
    estimate_spin_axis,
)

__all__ = [
    "ELEVATION_BINS",
    "MAX_COLLISIONS",
    "MAX_COLUMNS",
    "MAX_RANGE",
    "METHODS",
    "MIN_BEAM_CONCENTRATION",
    "MIN_OCCUPANCY",
    "RING_REUSE_COST",
    "SPIN_AXIS_MAX_TILT_DEG",
    "SPIN_AXIS_MIN_GAIN",
    "SPIN_AXIS_MIN_TILT_DEG",
    "TWO_PI",
    "WARN_COLLISIONS",
    "OrganizeReport",
    "OrganizeSummary",
    "Organizer",
    "beam_concentration",
    "estimate_beam_offset",
    "estimate_beams",
    "estimate_spin_axis",
    "warm_up",
]
