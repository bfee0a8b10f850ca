"""Label codes shared by every stage, and mappings from reference label sets.

The codes follow ``DESIGN.md``: LAS/ASPRS codes where ASPRS has a class, user codes
(64 and up) otherwise. Every output of this package keeps one ``uint8`` code per input
slot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NO_RETURN = 0
UNCLASSIFIED = 1
GROUND = 2
VEGETATION = 5
BUILDING = 6
NOISE = 7
TRUNK = 64
VEHICLE = 65
CURB = 66
POLE = 67
HORIZONTAL = 68
VERTICAL = 69


@dataclass(frozen=True)
class LabelInfo:
    """Name and display colour (RGB, 0-255) of one label code."""

    code: int
    name: str
    color: tuple[int, int, int]


LABELS: tuple[LabelInfo, ...] = (
    LabelInfo(NO_RETURN, "no_return", (0, 0, 0)),
    LabelInfo(UNCLASSIFIED, "unclassified", (160, 160, 160)),
    LabelInfo(GROUND, "ground", (70, 110, 230)),
    LabelInfo(VEGETATION, "vegetation", (40, 170, 60)),
    LabelInfo(BUILDING, "building", (220, 50, 50)),
    LabelInfo(NOISE, "noise", (255, 0, 255)),
    LabelInfo(TRUNK, "trunk", (140, 90, 40)),
    LabelInfo(VEHICLE, "vehicle", (250, 200, 0)),
    LabelInfo(CURB, "curb", (0, 220, 220)),
    LabelInfo(POLE, "pole", (255, 140, 0)),
    LabelInfo(HORIZONTAL, "horizontal", (120, 160, 255)),
    LabelInfo(VERTICAL, "vertical", (255, 120, 120)),
)

CODE_TO_NAME: dict[int, str] = {info.code: info.name for info in LABELS}
NAME_TO_CODE: dict[str, int] = {info.name: info.code for info in LABELS}

#: SemanticKITTI semantic ids (``label & 0xFFFF``) mapped to our codes. Ids not listed map
#: to ``UNCLASSIFIED``. Ground, building and noise groups follow the scoring classes of the
#: PRC paper's urban evaluation: ground = road, parking, sidewalk, other-ground,
#: lane-marking, terrain; building = building, fence, other-structure.
SEMANTIC_KITTI_TO_CODE: dict[int, int] = {
    0: UNCLASSIFIED,  # unlabeled
    1: NOISE,  # outlier
    10: VEHICLE,  # car
    11: VEHICLE,  # bicycle
    13: VEHICLE,  # bus
    15: VEHICLE,  # motorcycle
    16: VEHICLE,  # on-rails
    18: VEHICLE,  # truck
    20: VEHICLE,  # other-vehicle
    30: UNCLASSIFIED,  # person
    31: UNCLASSIFIED,  # bicyclist
    32: UNCLASSIFIED,  # motorcyclist
    40: GROUND,  # road
    44: GROUND,  # parking
    48: GROUND,  # sidewalk
    49: GROUND,  # other-ground
    50: BUILDING,  # building
    51: BUILDING,  # fence
    52: BUILDING,  # other-structure
    60: GROUND,  # lane-marking
    70: VEGETATION,  # vegetation
    71: TRUNK,  # trunk
    72: GROUND,  # terrain
    80: POLE,  # pole
    81: POLE,  # traffic-sign
    99: UNCLASSIFIED,  # other-object
    252: VEHICLE,  # moving-car
    253: UNCLASSIFIED,  # moving-bicyclist
    254: UNCLASSIFIED,  # moving-person
    255: UNCLASSIFIED,  # moving-motorcyclist
    256: VEHICLE,  # moving-on-rails
    257: VEHICLE,  # moving-bus
    258: VEHICLE,  # moving-truck
    259: VEHICLE,  # moving-other-vehicle
    66: CURB,  # not a SemanticKITTI class: our simulator's KITTI export writes curbs as 66
}

#: Our codes written as SemanticKITTI ids (the simulator's KITTI export); inverse of the
#: table above for every code that has an id.
CODE_TO_SEMANTIC_KITTI: dict[int, int] = {
    UNCLASSIFIED: 0,
    NOISE: 1,
    VEHICLE: 10,
    GROUND: 40,
    BUILDING: 50,
    VEGETATION: 70,
    TRUNK: 71,
    POLE: 80,
    CURB: 66,
}

_SEMKITTI_LUT = np.full(1 << 16, UNCLASSIFIED, dtype=np.uint8)
for _sem, _code in SEMANTIC_KITTI_TO_CODE.items():
    _SEMKITTI_LUT[_sem] = _code


def from_semantic_kitti(raw: np.ndarray) -> np.ndarray:
    """Map SemanticKITTI ``uint32`` labels to our ``uint8`` codes.

    Parameters
    ----------
    raw : ndarray of uint32
        SemanticKITTI labels, semantic id in the lower 16 bits, instance in the upper 16.

    Returns
    -------
    ndarray of uint8
        One code per input label, same shape.
    """
    return _SEMKITTI_LUT[np.asarray(raw, dtype=np.uint32) & 0xFFFF]


def to_semantic_kitti(codes: np.ndarray, instances: np.ndarray | None = None) -> np.ndarray:
    """Encode our codes (and instance ids) as SemanticKITTI ``uint32`` labels."""
    lut = np.zeros(256, dtype=np.uint32)
    for code, sem in CODE_TO_SEMANTIC_KITTI.items():
        lut[code] = sem
    out = lut[np.asarray(codes, dtype=np.uint8)]
    if instances is not None:
        out |= (np.asarray(instances, dtype=np.uint32) & 0xFFFF) << 16
    return out


def instances_from_semantic_kitti(raw: np.ndarray) -> np.ndarray:
    """Instance ids (upper 16 bits) of SemanticKITTI labels as ``uint32``."""
    return np.asarray(raw, dtype=np.uint32) >> 16


def to_label_file(codes: np.ndarray) -> np.ndarray:
    """Encode our codes as SemanticKITTI-style ``uint32`` entries (code in the lower 16 bits)."""
    return np.asarray(codes, dtype=np.uint32) & 0xFFFF


def names(codes: np.ndarray | list[int]) -> list[str]:
    """Names of label codes (``code_<n>`` for codes outside the table)."""
    return [CODE_TO_NAME.get(int(c), f"code_{int(c)}") for c in codes]


def color_lut() -> np.ndarray:
    """RGB colour per code as a ``(256, 3) uint8`` lookup table (grey for unknown codes)."""
    lut = np.full((256, 3), 128, dtype=np.uint8)
    for info in LABELS:
        lut[info.code] = info.color
    return lut
