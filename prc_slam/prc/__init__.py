"""Preregistration classification (Lehtola et al. 2019)."""

from prc_slam.prc.algorithm import (
    BlockResult,
    PRCState,
    PRCStream,
    classify_scan,
    column_density_ground,
    prc_block,
    support_thresholds,
    supported_mask,
)
from prc_slam.prc.config import PRCConfig
from prc_slam.prc.ground import GroundModelError, GroundResult, GroundState, column_ground

__all__ = [
    "BlockResult",
    "GroundModelError",
    "GroundResult",
    "GroundState",
    "PRCConfig",
    "PRCState",
    "PRCStream",
    "classify_scan",
    "column_density_ground",
    "column_ground",
    "prc_block",
    "support_thresholds",
    "supported_mask",
]
