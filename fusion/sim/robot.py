"""The true robot: a differential drive following a route, integrated at the odometry rate.

Controller (line-following pure pursuit), per step of length dt:

* progress along the current leg a→b (unit u, length L): ``s = (p − a)·u``; the leg is done when
  ``s ≥ L − 5 cm`` and the next one starts;
* target ``q = a + (max(s, 0) + lookahead)·u`` (on the leg's line, so the robot converges back to
  the line instead of cutting corners), heading error ``e = wrap(atan2(q − p) − θ)``;
* ``ω_cmd = clip(k·e, ±ω_max)``; ``v_cmd = v_max·max(0, cos e)⁴`` (0 when |e| > 60°: turn in
  place), limited to ``√(v_c² + 2·a_max·(L − s))`` so the robot slows down to the corner speed
  ``v_c = v_max·max(0, 1 − φ/45°)`` before a turn of φ;
* v and ω change by at most ``a_max·dt`` and ``α_max·dt``;
* unicycle with the midpoint rule: ``ds = v·dt``, ``dθ = ω·dt``,
  ``x += ds·cos(θ + dθ/2)``, ``y += ds·sin(θ + dθ/2)``, ``θ += dθ``.

The odometry is built from the same (ds, dθ) per step, so with no wheel errors its increments
equal the true ones exactly. A kidnap moves the true pose between two steps without any (ds, dθ).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.sim.config import Kidnap, RobotConfig
from fusion.sim.routes import Route
from houghloc.geometry import wrap_scalar

FloatArray = NDArray[np.float64]

_REACHED = 0.05  # m before a leg's end at which the next leg starts


@dataclass(frozen=True)
class Trajectory:
    """True poses at the integration steps (N×3) and the wheel motion between them ((N−1)×2:
    ds, dθ). ``kidnapped[k]`` is True if a kidnap happened between steps k and k+1."""

    poses: FloatArray
    motion: FloatArray
    kidnapped: NDArray[np.bool_]



def drive(route: Route, cfg: RobotConfig, dt: float, n_steps: int,
          kidnaps: Sequence[Kidnap] = (), start_pose: FloatArray | None = None) -> Trajectory:
    """Integrate the controller for ``n_steps`` poses (the first is the start pose).

    Kidnap k is applied between the step at which ``t = k.t`` is reached (t measured from the
    start) and the next one.
    """
    a_pts, b_pts = route.legs()
    n_legs = len(a_pts)
    d = b_pts - a_pts
    lengths = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(lengths, 1e-12)[:, None]
    # Turn at the end of each leg → how slowly to take the corner.
    nxt = np.roll(u, -1, axis=0)
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", u, nxt), -1.0, 1.0))
    if not route.loop:
        turn[-1] = math.pi  # stop at the final waypoint
    v_corner = cfg.v_max * np.clip(1.0 - turn / (math.pi / 4), 0.0, 1.0)
    a_list, u_list = a_pts.tolist(), u.tolist()
    len_list, vc_list = lengths.tolist(), v_corner.tolist()

    pose = route.start_pose() if start_pose is None else np.asarray(start_pose, dtype=float)
    x, y, th = (float(c) for c in pose)
    v = w = 0.0
    leg = 0
    finished = False
    kid = sorted(kidnaps, key=lambda k: k.t)
    kid_steps = [(math.ceil(k.t / dt - 1e-9), k) for k in kid]
    ki = 0

    poses = np.empty((n_steps, 3))
    motion = np.empty((max(n_steps - 1, 0), 2))
    kidnapped = np.zeros(max(n_steps - 1, 0), dtype=bool)
    vmax, wmax, k_gain, look = cfg.v_max, cfg.omega_max, cfg.heading_gain, cfg.lookahead
    dv_max, dw_max = cfg.accel_max * dt, cfg.alpha_max * dt
    two_a = 2.0 * cfg.accel_max
    for step in range(n_steps):
        poses[step] = (x, y, th)
        if step == n_steps - 1:
            break
        # --- leg bookkeeping
        ax, ay = a_list[leg]
        ux, uy = u_list[leg]
        s = (x - ax) * ux + (y - ay) * uy
        while not finished and s >= len_list[leg] - _REACHED:
            if leg + 1 < n_legs:
                leg += 1
            elif route.loop:
                leg = 0
            else:
                finished = True
                break
            ax, ay = a_list[leg]
            ux, uy = u_list[leg]
            s = (x - ax) * ux + (y - ay) * uy
        # --- commands
        if finished:
            v_cmd = w_cmd = 0.0
        else:
            ahead = max(s, 0.0) + look
            err = wrap_scalar(math.atan2(ay + ahead * uy - y, ax + ahead * ux - x) - th)
            w_cmd = max(-wmax, min(wmax, k_gain * err))
            c = math.cos(err)
            v_cmd = vmax * c**4 if abs(err) < math.pi / 3 else 0.0
            remaining = max(len_list[leg] - s - _REACHED, 0.0)
            v_cmd = min(v_cmd, math.sqrt(vc_list[leg] ** 2 + two_a * remaining) + 0.02)
        v += max(-dv_max, min(dv_max, v_cmd - v))
        w += max(-dw_max, min(dw_max, w_cmd - w))
        ds, dth = v * dt, w * dt
        mid = th + 0.5 * dth
        x += ds * math.cos(mid)
        y += ds * math.sin(mid)
        th = wrap_scalar(th + dth)
        motion[step] = (ds, dth)
        # --- kidnaps: the world moves the robot, the wheels do not turn
        while ki < len(kid_steps) and kid_steps[ki][0] <= step + 1:
            k = kid_steps[ki][1]
            x, y, th = x + k.dx, y + k.dy, wrap_scalar(th + k.dtheta)
            kidnapped[step] = True
            ki += 1
    return Trajectory(poses, motion, kidnapped)
