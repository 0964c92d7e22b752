"""Scenario simulator: a robot with wheel odometry, a 2D laser and/or a camera-line sensor in a
segment map with unmapped clutter and moving obstacles. Deterministic by seed.

Whole runs::

    from fusion.sim import scenario_preset, simulate, write_run
    run = simulate(scenario_preset("office-laser", seed=1))
    for event in run.events(): ...            # Odometry, Scan, PointSet, Truth in arrival order
    write_run(run, "runs/sim")                # log.carmen, gt.tum, map.yaml, scenario.yaml, …

Single measurements (accuracy tests)::

    pose = random_free_pose(m, rng)
    scan = laser_scan(m, pose, rng, LaserConfig(sigma=0.0), obstacles=discs, clutter=boxes)
    frame = camera_points(m, pose, rng, CameraConfig())

Labels of simulated points: map segment index ≥ 0, −1 no return, −2 moving obstacle, −3 clutter,
−4 spurious/false.
"""

from fusion.io.camera_points import read_camera_points
from fusion.sim.camera import CameraFrame, camera_points
from fusion.sim.config import (
    CameraConfig,
    ClutterConfig,
    Kidnap,
    LaserConfig,
    ObstacleGroup,
    OdometryConfig,
    OdometryGap,
    RobotConfig,
    RouteConfig,
    ScenarioConfig,
)
from fusion.sim.files import load_scenario, write_run
from fusion.sim.landmarks import landmark_sightings
from fusion.sim.laser import (
    CLUTTER,
    MOVING_OBSTACLE,
    NO_RETURN,
    SPURIOUS,
    LaserScan,
    beam_angles,
    laser_scan,
)
from fusion.sim.presets import PRESETS, scenario_preset
from fusion.sim.run import SimRun, SimulationError, path_crosses_walls, simulate
from fusion.sim.scene import obstacle_fraction, place_obstacles_near
from fusion.sim.world import MAPS_DIR, make_clutter, random_free_point, random_free_pose

__all__ = [
    "CLUTTER",
    "MAPS_DIR",
    "MOVING_OBSTACLE",
    "NO_RETURN",
    "PRESETS",
    "SPURIOUS",
    "CameraConfig",
    "CameraFrame",
    "ClutterConfig",
    "Kidnap",
    "LaserConfig",
    "LaserScan",
    "ObstacleGroup",
    "OdometryConfig",
    "OdometryGap",
    "RobotConfig",
    "RouteConfig",
    "ScenarioConfig",
    "SimRun",
    "SimulationError",
    "beam_angles",
    "camera_points",
    "landmark_sightings",
    "laser_scan",
    "load_scenario",
    "make_clutter",
    "obstacle_fraction",
    "path_crosses_walls",
    "place_obstacles_near",
    "random_free_point",
    "random_free_pose",
    "read_camera_points",
    "scenario_preset",
    "simulate",
    "write_run",
]
