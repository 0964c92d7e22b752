"""The map YAML as a file: its entries validated with pydantic, and every problem described with
the entry it is in (:meth:`houghloc.segment_map.SegmentMap.from_dict`).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator


class _SegmentEntry(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)
    id: str | None = None
    kind: Literal["wall", "line"] = "wall"
    start: tuple[float, float] = Field(alias="from")
    end: tuple[float, float] = Field(alias="to")

    @field_validator("start", "end")
    @classmethod
    def _finite(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not all(math.isfinite(c) for c in v):
            raise ValueError("coordinates must be finite numbers")
        return v


class _LandmarkEntry(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)
    id: str
    at: tuple[float, float]


class MapFile(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str = "unnamed"
    frame: str = "map"
    units: Literal["m"] = "m"
    segments: list[_SegmentEntry] = Field(min_length=1)
    # distinguishable point features (e.g. the RoboCup goals' colours); optional
    landmarks: list[_LandmarkEntry] = Field(default_factory=list)


def describe_error(exc: ValidationError, raw: dict) -> str:
    """Turn the first pydantic error into 'segment #i (id 'x'): field: problem'."""
    err = exc.errors()[0]
    loc = list(err["loc"])
    where = ""
    if len(loc) >= 2 and loc[0] == "segments" and isinstance(loc[1], int):
        i = loc[1]
        seg = raw.get("segments", [None] * (i + 1))[i]
        sid = seg.get("id") if isinstance(seg, dict) else None
        where = f"segment #{i}" + (f" (id {sid!r})" if sid is not None else "") + ": "
        loc = loc[2:]
    field = ".".join(str(p) for p in loc if not isinstance(p, int)) or "entry"
    field = {"start": "from", "end": "to"}.get(field, field)
    msg = err["msg"]
    if err["type"] == "missing":
        msg = "is missing"
    elif err["type"] == "too_short" and field == "segments":
        msg = "the map has no segments"
    return f"{where}{field!r} {msg}" if msg == "is missing" else f"{where}{field}: {msg}"
