"""Online per-scan-line detectors (Stamos et al., paper 001). So far: scan lines, the summary
statistics of Sec. 3 and the coarse H / V / vegetation classifier of Sec. 4 (with the less
sensitive vegetation detector T' of Sec. 7.1)."""

from prc_slam.online.coarse import CoarseParams, coarse_classify, scan_lines

__all__ = ["CoarseParams", "coarse_classify", "scan_lines"]
