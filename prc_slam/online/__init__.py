"""Online per-scan-line detectors (Stamos et al., paper 001). So far: scan lines, the summary
statistics of Sec. 3, the coarse H / V / vegetation classifier of Sec. 4 (with the less
sensitive vegetation detector T' of Sec. 7.1) and the ground algorithm of Sec. 5."""

from prc_slam.online.coarse import CoarseParams, CoarseResult, coarse_classify, scan_lines
from prc_slam.online.ground import GroundDetector, GroundParams

__all__ = ["CoarseParams", "CoarseResult", "GroundDetector", "GroundParams", "coarse_classify", "scan_lines"]
