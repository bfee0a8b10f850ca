"""Online per-scan-line detectors (Stamos et al., paper 001). So far: scan lines, the summary
statistics of Sec. 3, the coarse H / V / vegetation classifier of Sec. 4 (with the less
sensitive vegetation detector T' of Sec. 7.1), the ground algorithm of Sec. 5 and the curb
algorithm of Sec. 6. The car algorithm (Sec. 7) and the combination of Sec. 8 are to come."""

from prc_slam.online.coarse import CoarseParams, CoarseResult, coarse_classify, scan_lines
from prc_slam.online.curb import CurbParams, CurbResult, detect_curbs
from prc_slam.online.detector import OnlineDetector, OnlineResult
from prc_slam.online.ground import GroundDetector, GroundParams

__all__ = [
    "CoarseParams",
    "CoarseResult",
    "CurbParams",
    "CurbResult",
    "GroundDetector",
    "GroundParams",
    "OnlineDetector",
    "OnlineResult",
    "coarse_classify",
    "detect_curbs",
    "scan_lines",
]
