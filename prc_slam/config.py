"""Configuration: one pydantic model per stage, defaults = the papers' parameters.

The composed :class:`Config` loads from YAML, is overridable from the CLI, and is written
next to every result.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from prc_slam.filtering import FilterConfig
from prc_slam.mapclass.classify import MapClassConfig
from prc_slam.odometry.classaware import ClassAwareConfig
from prc_slam.odometry.kiss import OdometryConfig
from prc_slam.prc.config import PRCConfig


class Config(BaseModel):
    """All stages' configuration, composed."""

    model_config = ConfigDict(extra="forbid")

    prc: PRCConfig = Field(default_factory=PRCConfig)
    filter: FilterConfig = Field(default_factory=FilterConfig)
    odometry: OdometryConfig = Field(default_factory=OdometryConfig)
    mapclass: MapClassConfig = Field(default_factory=MapClassConfig)
    classaware: ClassAwareConfig = Field(default_factory=ClassAwareConfig)

    @classmethod
    def from_yaml(cls, path: str | Path, base: Config | None = None) -> Config:
        """Load a YAML file; missing keys take their values in ``base`` (e.g. the command line's
        preset), else their defaults. A key given replaces the base's value whole (``source_cell:
        {}`` means no source cells)."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
            what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise ValueError(f"{path}: cannot read config{where}: {what}") from exc
        if not isinstance(data, dict):
            raise ValueError(f"{path}: config must be a mapping, got {type(data).__name__}")
        if base is not None:
            merged = base.model_dump()
            for section, values in data.items():
                if isinstance(values, dict) and isinstance(merged.get(section), dict):
                    merged[section] = {**merged[section], **values}
                else:
                    merged[section] = values
            data = merged
        try:
            return cls.model_validate(data)
        except ValidationError as exc:  # name the file and the keys as written in it (prc.k, not --prc.k)
            problems = "; ".join(
                f"{'.'.join(str(p) for p in err.get('loc', ())) or 'config'}: {err.get('msg', 'invalid')}"
                + (f" (got {err['input']!r})" if "input" in err and err.get("type") != "missing" else "")
                for err in exc.errors()
            )
            raise ValueError(f"{path}: {problems}") from exc

    def to_yaml(self, path: str | Path) -> None:
        """Write the configuration actually used."""
        Path(path).write_text(yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False))
