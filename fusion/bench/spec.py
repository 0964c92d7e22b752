"""The sweep spec: which runs, which settings, which methods, which protocols.

A spec is a YAML file::

    data: ../shared/data              # base folder of relative log paths (default: the spec's)
    runs:
      - name: aces
        log: aces/aces-corrected.log.gz            # what is localized (raw odometry + scans)
        build_from: aces/aces-corrected.log.gz     # the corrected log the maps are built from
      - name: intel
        log: intel/scan_intel.mat
        build_from: intel/intel.gfs.log
        reference: intel/intel.gfs.log             # another file's corrected poses
        relations: intel/intel.relations
        time_offset: 976052857.337284
        initial_pose: [0.0, 0.0, 0.0]
      - name: office
        log: sim-office                            # a `houghloc sim` directory
        map: sim-office/map.yaml                   # a given segment map instead of build_from
        reference: sim-office/gt.tum               # a TUM reference
    grid:                                          # houghloc settings, every combination
      filter.gate_probability: [0.99, 0.999]
    methods: [houghloc, icp, amcl]
    protocols: [same-run, held-out-map, global-start]

Relative paths are taken from ``data``, itself relative to the spec file. Every problem is a
:class:`SpecError` naming the spec file and the field.
"""

from __future__ import annotations

import itertools
import json
import math
from enum import StrEnum
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from houghloc.yaml_io import read_yaml, validated


class SpecError(ValueError):
    """A sweep spec that cannot be run; the message names the file and the field."""


class Protocol(StrEnum):
    SAME_RUN = "same-run"
    """The map is built from the very scans being localized (flatters every matcher)."""
    HELD_OUT_MAP = "held-out-map"
    """The map is built from scans the localized span does not contain."""
    GLOBAL_START = "global-start"
    """The same-run map, no initial pose: how long until right and staying right."""


class Method(StrEnum):
    HOUGHLOC = "houghloc"
    ODOMETRY = "odometry"
    """Dead reckoning from the start pose: the floor every method should beat."""
    ICP = "icp"
    """Scan-to-map point-to-point ICP (small_gicp), started from the odometry prediction."""
    AMCL = "amcl"
    """nav2's AMCL (nav2_amcl's own code) with nav2's default parameters: likelihood field."""
    AMCL_TUNED = "amcl-tuned"
    """The same AMCL with one parameter set tuned over all the buildings."""
    AMCL_BEAM = "amcl-beam"
    """nav2's AMCL with its defaults and its beam model."""
    MRPT = "mrpt"
    """MRPT's pf-localization (Debian package mrpt-apps), likelihood field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class RunSpec(_Strict):
    """One log to localize and where its map and reference come from."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    log: Path | None = Field(None, description="the log to localize (not with `scenario`)")
    scenario: str | None = Field(
        None, description="a simulated scenario (`houghloc sim --scenario`) drawn from `seed` "
        "by the task itself: its log, map and ground truth replace log, map and reference")
    seed: int = 0
    duration: float | None = Field(None, gt=0.0, description="s of the scenario (its own)")
    build_from: Path | None = Field(
        None, description="a log whose scans carry reference poses (a corrected log), or any log "
        "when `reference` gives the poses: the maps are built from its scans")
    map: Path | None = Field(None, description="a segment-map YAML used as it is (same-run only)")
    reference: Path | None = Field(
        None, description="reference poses: a corrected log or a TUM file (default: the log's "
        "own corrected poses)")
    relations: Path | None = None
    time_offset: float = Field(0.0, description="s subtracted from the relations' stamps")
    initial_pose: tuple[float, float, float] | None = Field(
        None, description="start pose of the localized span (default: its first reference pose)")
    config: Path | None = Field(
        None, description="a localizer YAML describing the sensor (beams, mount, maximum range)")
    max_scans: int | None = Field(None, gt=0, description="only the first N scans of the log")

    @model_validator(mode="after")
    def _one_map_source(self) -> RunSpec:
        if self.scenario is not None:
            if any(v is not None for v in (self.log, self.build_from, self.map, self.reference)):
                raise ValueError("a scenario run brings its own log, map and reference: give "
                                 "none of log, build_from, map and reference")
            return self
        if self.log is None:
            raise ValueError("give log (a log to localize) or scenario (a simulated one)")
        if (self.build_from is None) == (self.map is None):
            raise ValueError("give exactly one of build_from (a corrected log) and map (a "
                             "segment-map YAML)")
        if self.initial_pose is not None and not all(map(math.isfinite, self.initial_pose)):
            raise ValueError("initial_pose must be finite")
        return self


class GeneratedRuns(_Strict):
    """Runs of a simulated scenario, one per seed of an inclusive range: ``{scenario: building,
    seeds: [0, 49]}`` names them ``building-0`` … ``building-49``."""

    scenario: str = "building"
    seeds: tuple[int, int]
    duration: float | None = Field(None, gt=0.0)

    @model_validator(mode="after")
    def _ordered(self) -> GeneratedRuns:
        if self.seeds[0] > self.seeds[1]:
            raise ValueError("seeds must be [first, last] with first <= last")
        return self

    def runs(self) -> list[RunSpec]:
        return [RunSpec(name=f"{self.scenario}-{seed}", scenario=self.scenario, seed=seed,
                        duration=self.duration)
                for seed in range(self.seeds[0], self.seeds[1] + 1)]


class SweepSpec(_Strict):
    data: Path | None = None
    runs: list[RunSpec] = Field(default_factory=list)
    generated: list[GeneratedRuns] = Field(
        default_factory=list, description="simulated runs, a seed range each (added to runs)")
    grid: dict[str, list[Any]] = Field(
        default_factory=dict, description="houghloc config overrides: dotted key → values")
    methods: list[Method] = Field(default_factory=lambda: [Method.HOUGHLOC], min_length=1)
    protocols: list[Protocol] = Field(default_factory=lambda: [Protocol.SAME_RUN], min_length=1)
    max_dt: float = Field(0.006, gt=0.0, description="s, estimate ↔ reference association")

    @field_validator("grid")
    @classmethod
    def _grid_values(cls, grid: dict[str, list[Any]]) -> dict[str, list[Any]]:
        for key, values in grid.items():
            if not key or any(not part for part in key.split(".")):
                raise ValueError(f"{key!r} is not a dotted config key")
            if not values:
                raise ValueError(f"{key}: no values")
        return grid

    @model_validator(mode="after")
    def _unique_names(self) -> SweepSpec:
        if not self.all_runs:
            raise ValueError("no run: give runs or generated")
        names = [r.name for r in self.all_runs]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"run names must be unique: {', '.join(twice)}")
        return self

    @property
    def all_runs(self) -> list[RunSpec]:
        """The runs given one by one, then the generated ones, seed by seed."""
        return [*self.runs, *(r for g in self.generated for r in g.runs())]

    def settings(self) -> list[dict[str, Any]]:
        """Every combination of the grid's values ({} when the grid is empty)."""
        keys = list(self.grid)
        return [dict(zip(keys, values, strict=True))
                for values in itertools.product(*(self.grid[k] for k in keys))]


def settings_label(settings: dict[str, Any]) -> str:
    """The settings as they appear in results.csv: compact JSON, keys sorted ({} = defaults)."""
    return json.dumps(settings, sort_keys=True, separators=(",", ":"))


def load_spec(path: str | Path) -> SweepSpec:
    """The spec at ``path`` with every path made absolute and checked to exist."""
    path = Path(path)
    raw = read_yaml(path, SpecError, "spec")
    spec = validated(SweepSpec, raw, SpecError, "spec", str(path))
    base = path.resolve().parent
    data = (base / spec.data) if spec.data is not None else base
    runs = []
    for i, run in enumerate(spec.runs):
        fields: dict[str, Any] = {}
        # a scenario is simulated by its task: no file of it to find
        names = ("config",) if run.scenario is not None else (
            "log", "build_from", "map", "reference", "relations", "config")
        for name in names:
            value = getattr(run, name)
            if value is None:
                continue
            resolved = value if value.is_absolute() else (data / value)
            if not resolved.exists():
                raise SpecError(f"spec {path}: runs.{i}.{name}: {resolved} does not exist")
            fields[name] = resolved
        runs.append(run.model_copy(update=fields))
    runs += [r for g in spec.generated for r in g.runs()]
    for key in spec.grid:  # an unknown key fails here, not in a worker an hour later
        _check_setting(path, key, spec.grid[key])
    return spec.model_copy(update={"runs": runs, "generated": [], "data": data})


def _check_setting(path: Path, key: str, values: list[Any]) -> None:
    from fusion.config import ConfigError

    for value in values:
        try:
            apply_settings(None, {key: value})
        except ConfigError as error:
            raise SpecError(f"spec {path}: grid.{key}: {str(error).split(': ', 2)[-1]}") from None


def apply_settings(config: Path | None, settings: dict[str, Any]):
    """The localizer config (the file's, or the defaults) with dotted-key overrides applied.
    Raises :class:`fusion.config.ConfigError` naming the key for an unknown or invalid one."""
    from fusion.config import ConfigError, LocalizerConfig

    raw: dict[str, Any] = {}
    if config is not None:
        loaded = read_yaml(config, ConfigError, "config") or {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"config {config}: expected a mapping")
        raw = loaded
    for key, value in settings.items():
        node = raw
        *parents, leaf = key.split(".")
        for name in parents:
            node = node.setdefault(name, {})
            if not isinstance(node, dict):
                raise ConfigError(f"config: {key}: {name!r} is not a group of settings")
        node[leaf] = value
    source = f"{config or 'defaults'} with {settings_label(settings)}"
    return LocalizerConfig.from_dict(raw, source=source)
