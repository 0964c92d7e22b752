"""Named scenarios.

* ``robocup-laser``: the paper's field, a 2D laser (361 beams, 180°, 10 m), three other robots
  (r = 0.25 m, 0.5 m/s) moving on the pitch, 5 minutes, default wheel errors.
* ``robocup-camera``: the same field seen only by the camera-line sensor (60°, 0.3–4 m, 5 Hz,
  3 false points per frame, 0.2 s latency — image processing takes "a few tenths of a second"
  in the paper), with the three moving robots.
* ``office-laser``: the office floor, a 2D laser, four people (r = 0.2 m, 0.8 m/s), eight unmapped
  boxes, 5 minutes along the corridor-and-rooms loop.
* ``building``: a floor plan, tour and faulty robot drawn from the seed
  (:mod:`fusion.sim.building`).
"""

from __future__ import annotations

from fusion.sim.config import (
    CameraConfig,
    ClutterConfig,
    LaserConfig,
    ObstacleGroup,
    ScenarioConfig,
)

BUILDING = "building"
"""A building drawn from the seed (:mod:`fusion.sim.building`): a new floor plan per seed."""

_ROBOTS = ObstacleGroup(count=3, radius=0.25, speed=0.5, turn_noise=0.5, kind="robot")
_PEOPLE = ObstacleGroup(count=4, radius=0.2, speed=0.8, turn_noise=0.8, kind="person")

PRESETS: dict[str, ScenarioConfig] = {
    "robocup-laser": ScenarioConfig(
        name="robocup-laser", map="robocup.yaml", duration=300.0,
        laser=LaserConfig(), camera=None, obstacles=[_ROBOTS],
    ),
    "robocup-camera": ScenarioConfig(
        name="robocup-camera", map="robocup.yaml", duration=300.0,
        laser=None, camera=CameraConfig(false_points=3.0, latency=0.2), obstacles=[_ROBOTS],
    ),
    "office-laser": ScenarioConfig(
        name="office-laser", map="office.yaml", duration=300.0,
        laser=LaserConfig(), camera=None, obstacles=[_PEOPLE], clutter=ClutterConfig(count=8),
    ),
}


def scenario_preset(name: str, seed: int = 0, duration: float | None = None) -> ScenarioConfig:
    """A named scenario with the given seed (and duration in seconds, if given)."""
    if name == BUILDING:
        from fusion.sim.building import building_scenario

        return building_scenario(seed, duration)
    try:
        cfg = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown scenario preset {name!r}; known: "
                         f"{', '.join([*PRESETS, BUILDING])}") from None
    update: dict[str, object] = {"seed": seed}
    if duration is not None:
        update["duration"] = float(duration)
    return ScenarioConfig.model_validate({**cfg.model_dump(), **update})
