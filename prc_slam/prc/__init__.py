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

__all__ = [
    "BlockResult",
    "PRCState",
    "PRCStream",
    "classify_scan",
    "column_density_ground",
    "prc_block",
    "support_thresholds",
    "supported_mask",
]
