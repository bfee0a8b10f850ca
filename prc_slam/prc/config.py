"""Parameters of preregistration classification (Lehtola et al. 2019, Sec. II), beside the stage."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class PRCConfig(BaseModel):
    """Parameters of preregistration classification (Lehtola et al. 2019, Sec. II).

    Names follow the paper: ``k`` scan lines per block, support thresholds ``xi_s``
    (adjacent-slice, eq. 5) and ``xi_p`` (in-slice, eq. 6), cover density ``rho_c`` (eq. 3),
    gradient tolerance ``alpha`` and minimal length ``d_c`` (eq. 9), area ``A`` and dilations
    ``gamma`` (eq. 11), and the forest column-density threshold (eq. 12).
    """

    model_config = ConfigDict(extra="forbid")

    mode: Literal["urban", "forest"] = "urban"
    k: int = Field(99, ge=1, description="scan lines per block (profiler); a sweep is one block")
    xi_s: float = Field(1.0, ge=0.0, description="adjacent-slice range threshold (m), eq. (5)")
    xi_p: float = Field(1.0, ge=0.0, description="in-slice range threshold (m), eq. (6)")
    rho_c: float = Field(1.0 / 3.0, gt=0.0, le=1.0, description="minimum support cover density, eq. (3)")
    in_slice_half: int = Field(4, ge=1, description="N_in-slice = r_{i-n}..r_{i+n} without i, eq. (8)")
    in_slice_reach: int = Field(
        4,
        ge=1,
        description="eq. (8) as the 2n closest returns of the scan line within this many columns each side "
        "(skipping slots without a return); <= in_slice_half: the paper's slots",
    )
    one_sided_incidence_deg: float | None = Field(
        None,
        ge=0.0,
        lt=90.0,
        description="one-sided rule: noise meeting either condition of eq. (4) under adaptive thresholds at this "
        "incidence is not isolated (one_sided); None: exactly one condition under the support thresholds",
    )
    alpha: float = Field(0.3, ge=0.0, lt=0.5, description="tolerance ratio of eq. (9)")
    d_c: float = Field(0.05, gt=0.0, description="minimal characteristic length (m), eq. (9)")
    gradient: Literal["symmetric", "literal"] = Field(
        "symmetric", description="eq. (9) as printed ('literal') or its symmetric form (see kernels)"
    )
    gradient_axes: Literal["in_slice", "both"] = Field(
        "in_slice", description="eq. (9) along the scan line only (paper) or also across scan lines"
    )
    A: int = Field(30, ge=1, description="area (pixels) from which a segment is smooth, eq. (11)")
    gamma: int = Field(2, ge=0, description="4-neighbour dilations of the nonsmooth set, Sec. II-E")
    boundary_votes: int = Field(3, ge=1, description="votes needed to carry a label over a block boundary")
    density_threshold: float = Field(1.0 / 3.0, description="forest ground: column smoothness density, eq. (12)")
    density_stride: int = Field(10, ge=1, description="forest ground: eq. (12) evaluated every n-th column")
    density_axis: Literal["columns", "rows"] | None = Field(
        None, description="eq. (12) along block columns (profiler, the paper) or along rings; None: by sensor"
    )
    density_window: int = Field(512, ge=1, description="rows axis: columns per density window")
    adaptive: bool = Field(False, description="scale xi_s, xi_p with the expected neighbour spacing")
    adaptive_incidence_deg: float = Field(
        85.0, ge=0.0, lt=90.0, description="adaptive mode: steepest incidence angle the thresholds allow for"
    )
    wrap_columns: bool | None = Field(None, description="columns wrap around (None: yes for spinning sensors)")
    ground: Literal["largest_smooth", "columns", "auto"] = Field(
        "largest_smooth",
        description="ground: the paper's rule (urban: the largest smooth patch, forest: eq. (12); Sec. II-F), the "
        "column ground of prc.ground (spinning sensors; in forest mode too), or auto (columns for spinning sensors, "
        "the paper's rule for profilers)",
    )
    ground_slope_deg: float = Field(
        7.0, ge=0.0, lt=45.0, description="column ground: steepest ground slope between a beam and the last ground"
    )
    ground_step: float = Field(0.05, ge=0.0, description="column ground: height tolerance (m) on top of the slope")
    ground_start: float = Field(
        0.4, gt=0.0, description="column ground: first ground return of a column within this of z_ref (m)"
    )
    ground_tau: float = Field(0.1, gt=0.0, description="column ground: distance (m) to the local ground height")
    ground_cell_deg: float = Field(3.0, gt=0.0, le=90.0, description="column ground: azimuth width of a cell")
    ground_cell_m: float = Field(1.0, gt=0.0, description="column ground: horizontal range depth of a cell (m)")
    ground_segment_share: float = Field(
        0.5, gt=0.0, le=1.0, description="column ground: seed share from which a smooth PRC segment joins"
    )

    @classmethod
    def preset(cls, name: str, **overrides: object) -> PRCConfig:
        """Presets. The paper's ``urban`` (k = 99, xi = 1.0 m, A = 30, gamma = 2) and ``forest``
        (k = 255, xi = 0.01 m); and ``multibeam``, our setting for spinning multi-beam sensors:
        urban plus thresholds scaled with the slot spacing, eq. (9) also across scan lines,
        ``d_c = 0.5 m``, N_in-slice as the closest returns within 12 columns, the one-sided rule at
        85 degrees and the column ground of :mod:`prc_slam.prc.ground` on spinning sensors."""
        presets: dict[str, dict[str, object]] = {
            "urban": {"mode": "urban", "k": 99, "xi_s": 1.0, "xi_p": 1.0, "A": 30, "gamma": 2},
            "forest": {"mode": "forest", "k": 255, "xi_s": 0.01, "xi_p": 0.01, "A": 30, "gamma": 2},
            # beyond the paper, measured on KITTI 00 frames 0-2 (README, "PRC on multi-beam data")
            "multibeam": {
                "mode": "urban",
                "k": 99,
                "xi_s": 1.0,
                "xi_p": 1.0,
                "A": 30,
                "gamma": 2,
                "adaptive": True,
                "adaptive_incidence_deg": 89.0,
                "gradient_axes": "both",
                "d_c": 0.5,
                "in_slice_reach": 12,
                "one_sided_incidence_deg": 85.0,
                "ground": "auto",
            },
        }
        if name not in presets:
            raise ValueError(f"unknown PRC preset {name!r}; choose from {sorted(presets)}")
        return cls(**{**presets[name], **overrides})

    @classmethod
    def named(cls, preset: str, mode: str = "urban", adaptive: bool | None = None) -> PRCConfig:
        """``--preset paper|multibeam --mode urban|forest``: the paper's preset of ``mode``, or
        ``multibeam`` in ``mode``; ``adaptive`` when given."""
        if preset not in ("paper", "multibeam"):
            raise ValueError(f"unknown preset {preset!r}; choose from multibeam, paper")
        cfg = cls.preset("multibeam" if preset == "multibeam" else mode)
        updates: dict[str, object] = {}
        if preset == "multibeam" and mode == "forest":
            updates["mode"] = "forest"
        if adaptive is not None:
            updates["adaptive"] = adaptive
        return cfg.model_copy(update=updates) if updates else cfg

    @classmethod
    def for_sensor(cls, sensor: object, mode: str = "urban", adaptive: bool | None = None) -> tuple[PRCConfig, str]:
        """The preset a sensor's sweeps call for, and why (``--preset auto``): ``multibeam`` for a
        spinning sensor of several beams (the paper's parameters, made for one scan line of a
        mobile-mapping profiler, take the largest smooth patch for ground and 1 m thresholds for
        every beam: ground F1 0.63 against 0.96 on KITTI 00 frames 0-2), the paper's for anything
        else (profilers, solid-state grids, one beam); in ``mode``, ``adaptive`` when given."""
        from prc_slam.scan import SpinningSensor

        beams = len(getattr(sensor, "altitude", ()))
        if isinstance(sensor, SpinningSensor) and beams >= 2:
            return cls.named(
                "multibeam", mode, adaptive
            ), f"multibeam: the sweeps are from a {beams}-beam spinning sensor"
        if sensor is None:
            kind = "no sweep of the first ones could be read to tell"
        elif isinstance(sensor, SpinningSensor):
            kind = "the input is a spinning sensor of one beam"
        else:
            kind = "the input is not a spinning sensor"
        return cls.named("paper", mode, adaptive), f"paper ({mode}): {kind}"


class AutoPreset:
    """``--preset auto``: the preset :meth:`PRCConfig.for_sensor` gives the first sweep of a run
    (in ``mode``, ``adaptive`` when given), kept for the rest of it; ``config`` and ``why`` hold
    the choice once made (None and "" before)."""

    def __init__(self, mode: str = "urban", adaptive: bool | None = None) -> None:
        self.mode, self.adaptive = mode, adaptive
        self.config: PRCConfig | None = None
        self.why = ""

    def resolve(self, sensor: object) -> PRCConfig:
        """The config of this run: chosen on the first call, from ``sensor``."""
        if self.config is None:
            self.config, self.why = PRCConfig.for_sensor(sensor, self.mode, self.adaptive)
        return self.config
