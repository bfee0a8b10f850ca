"""Online per-scan-line detectors (Stamos et al., paper 001). So far: scan lines, the summary
statistics of Sec. 3, the coarse H / V / vegetation classifier of Sec. 4 (with the less
sensitive vegetation detector T' of Sec. 7.1), the ground algorithm of Sec. 5 and the curb
algorithm of Sec. 6, the car algorithm of Sec. 7 with the combination of Sec. 8, and their
carriage to spinning multi-beam sensors (``spinning``: local ground along columns, car segments
along rings and columns, curb faces along columns)."""

from prc_slam.online.coarse import CoarseParams, CoarseResult, coarse_classify, scan_lines
from prc_slam.online.curb import CurbParams, CurbResult, detect_curbs
from prc_slam.online.detector import OnlineDetector, OnlineResult
from prc_slam.online.ground import GroundDetector, GroundParams
from prc_slam.online.spinning import SpinningCarParams, SpinningCars, detect_cars_spinning, detect_curbs_spinning

__all__ = [
    "CoarseParams",
    "CoarseResult",
    "CurbParams",
    "CurbResult",
    "GroundDetector",
    "GroundParams",
    "OnlineDetector",
    "OnlineResult",
    "SpinningCarParams",
    "SpinningCars",
    "coarse_classify",
    "detect_cars_spinning",
    "detect_curbs",
    "detect_curbs_spinning",
    "scan_lines",
]
