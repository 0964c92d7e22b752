"""How well a scan lies on the map's walls at a pose, and what that says of a tracking fix.

The fraction of a scan's points within the global matcher's inlier distance of a wall (looked
up in the map's distance transform) is the manager's one measure of fit. Judged against the
recent scans', it tells a fix that moved the scan off the walls (a misfit), a fix the matcher
could not vouch for but the scan does, and a prediction that still holds without any fix.
The fraction seen through the map's walls tells a belief the scan contradicts from one the map
merely does not explain (a room it lacks). Both make the scan's likelihood at a pose
(:meth:`ScanFit.shares`, :func:`fusion.hypotheses.scan_log_likelihood`), which weighs followed
hypotheses and judges the pose a local re-search found against the guess.
"""

from __future__ import annotations

import statistics
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.hypotheses import glass_log_odds, glass_points, moved_since
from fusion.settings.ambiguity import AmbiguityConfig
from houghloc import SegmentMap
from houghloc.hypothesis_scores import seen_directly, walls_seen_through
from houghloc.map_lookup import wall_distance

TRACKED_FITS = 200  # accepted scans whose fits tell what a right pose fits
MIN_HISTORY = 5  # fits needed before a median says what is usual
MIN_QUANTILE_HISTORY = 20  # accepted scans' fits needed before a low quantile of them says it


@dataclass
class ScanFit:
    """The fit measure and the recent fits it is judged against (``fit_window`` of each)."""

    map: SegmentMap
    config: AmbiguityConfig
    counts: Counter = field(default_factory=Counter)
    # fractions on walls: of the fixes used (misfit_ratio), of the guesses of accepted scans,
    # of the fixes that passed fix_fits, and of the latest TRACKED_FITS accepted guesses
    used: deque = field(init=False)
    guesses: deque = field(init=False)
    fixes: deque = field(init=False)
    tracked: deque = field(default_factory=lambda: deque(maxlen=TRACKED_FITS))
    glass: NDArray[np.bool_] = field(init=False)
    """per segment of the map: the walls tracking has seen through onto the walls beyond
    (glass, a door the map shows closed), a fact about the building that every pose followed
    later starts from (:meth:`learn_glass`)"""
    _glass_odom: NDArray | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        window = self.config.fit_window
        self.used, self.guesses, self.fixes = (
            deque(maxlen=window), deque(maxlen=window), deque(maxlen=window))
        self.glass = np.zeros(len(self.map.starts), dtype=bool)

    def learn_glass(self, pose: NDArray, points: NDArray, odom: NDArray | None,
                    kinds: tuple[str, ...] = ("wall",)) -> None:
        """An accepted scan at ``pose``: a wall its ``points`` were seen through is glass from
        now on where enough of them lie on the walls beyond for a followed pose to take it
        (:func:`~fusion.hypotheses.glass_points`), and where they lie there as behind
        glass rather than as a wrong pose's points would, by chance
        (:func:`~fusion.hypotheses.glass_log_odds` > 0): a fact about the building
        needs more than one pose's bargain, as a wrong pose tracked for a while sees through
        walls too. Looked at once the robot has moved by the bank's ``update_distance`` (or
        turned ``update_angle_deg``) since the last look: scans closer together see the same
        walls."""
        model = self.config.hypotheses
        if model is None or len(points) == 0 or "wall" not in kinds or odom is None:
            return
        if not moved_since(self._glass_odom, odom, model):
            return
        self._glass_odom = np.asarray(odom, float).copy()
        pose = np.asarray(pose, float)
        on = self._on_walls(pose.reshape(1, 3), points, kinds)[0]
        crossed = walls_seen_through(pose, points, self.map, kinds, _reach(points),
                                     self.config.global_match.visibility_margin, self.glass)
        through = np.bincount(crossed[crossed >= 0], minlength=len(self.glass))
        beyond = np.bincount(crossed[on & (crossed >= 0)], minlength=len(self.glass))
        self.glass[(beyond >= glass_points(model, len(points)))
                   & (glass_log_odds(model, beyond, through - beyond, len(points)) > 0.0)] = True

    def fractions(self, poses: NDArray, points: NDArray,
                  kinds: tuple[str, ...] = ("wall",)) -> NDArray[np.float64]:
        """:meth:`fraction` at each of ``poses`` (P×3) at once."""
        if len(points) == 0:
            return np.zeros(len(poses))
        gm = self.config.global_match
        walls = wall_distance(self.map, tuple(kinds), gm.dt_cell)
        return walls.on_walls(poses, points[:, 0], points[:, 1], gm.inlier_distance)

    def fraction(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...] = ("wall",)
                 ) -> float:
        """The fraction of ``points`` (robot frame) on the map's segments of ``kinds`` at
        ``pose``."""
        if len(points) == 0:
            return 0.0
        return float(self.fractions(np.asarray(pose, float).reshape(1, 3), points, kinds)[0])

    def seen_through(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...] = ("wall",)
                     ) -> float:
        """The fraction of ``points`` (robot frame) that the robot at ``pose`` could only have
        seen through one of the map's walls of ``kinds``: the ray to the point crosses it more
        than ``visibility_margin`` before the point (:func:`seen_directly`)."""
        if len(points) == 0:
            return 0.0
        return 1.0 - float(np.mean(self._seen(pose, points, kinds, _reach(points))))

    def shares(self, poses: NDArray, points: NDArray, kinds: tuple[str, ...] = ("wall",)
               ) -> NDArray[np.float64]:
        """At each of ``poses`` (P×3), the shares of ``points`` (robot frame) on a wall that
        the robot there sees directly (within the global matcher's inlier distance), seen
        through a wall (:meth:`seen_through`), and neither: P×3, each row summing to 1."""
        return self._shares(poses, points, kinds, None, 0)[0]

    def shares_with_glass(self, poses: NDArray, points: NDArray, glass: list[NDArray[np.bool_]],
                          glass_points: int, kinds: tuple[str, ...] = ("wall",)
                          ) -> tuple[NDArray[np.float64], list[NDArray[np.intp]]]:
        """:meth:`shares` where the robot at pose k sees through the walls ``glass[k]`` (per
        segment of the map) onto the walls beyond, and through any other wall that
        ``glass_points`` or more of the points, each on a wall beyond it, were seen through:
        the walls newly taken for glass at each pose are returned with the shares. A point seen
        through glass onto no wall is still seen through: a pose whose rays pass a wall onto
        nothing explains nothing by it (a pose straddling the building's outer wall)."""
        return self._shares(poses, points, kinds, glass, glass_points)

    def _shares(self, poses: NDArray, points: NDArray, kinds: tuple[str, ...],
                glass: list[NDArray[np.bool_]] | None, glass_points: int
                ) -> tuple[NDArray[np.float64], list[NDArray[np.intp]]]:
        poses = np.asarray(poses, float).reshape(-1, 3)
        out = np.zeros((len(poses), 3))
        taken = [np.zeros(0, np.intp) for _ in range(len(poses))]
        if len(points) == 0:
            out[:, 2] = 1.0
            return out, taken
        on = self._on_walls(poses, points, kinds)
        reach = _reach(points)  # the same points at every pose
        margin = self.config.global_match.visibility_margin
        for k, pose in enumerate(poses):
            seen = self._seen(pose, points, kinds, reach)
            if glass is not None:
                see_glass = np.asarray(glass[k], bool)
                crossed = walls_seen_through(pose, points, self.map, kinds, reach, margin,
                                             see_glass)
                counts = np.bincount(crossed[on[k] & (crossed >= 0)])
                taken[k] = np.flatnonzero(counts >= glass_points)
                if len(taken[k]):
                    see_glass = see_glass.copy()
                    see_glass[taken[k]] = True
                    crossed = walls_seen_through(pose, points, self.map, kinds, reach, margin,
                                                 see_glass)
                seen |= on[k] & (crossed < 0)  # seen through glass onto a wall
            _fill(out[k], on[k], seen)
        return out, taken

    def _on_walls(self, poses: NDArray, points: NDArray, kinds: tuple[str, ...]
                  ) -> NDArray[np.bool_]:
        """P×N: which points lie within the global matcher's inlier distance of a wall."""
        gm = self.config.global_match
        walls = wall_distance(self.map, tuple(kinds), gm.dt_cell)
        # float32 distances, compared in float32 as on_walls does
        return walls.at(poses, points[:, 0], points[:, 1]) <= np.float32(gm.inlier_distance)

    def _seen(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...], reach: float
              ) -> NDArray[np.bool_]:
        """Which of the (non-empty) ``points`` the robot at ``pose`` sees directly: the walls
        within ``reach`` (the farthest point's range, :func:`_reach`) are tried."""
        return seen_directly(np.asarray(pose, float), points, self.map, kinds, reach,
                             self.config.global_match.visibility_margin)

    def accepted(self, guess_fit: float) -> None:
        """A scan's fix was accepted: its guess's fit is what tracking fits here."""
        self.guesses.append(guess_fit)
        self.tracked.append(guess_fit)

    def guess_holds(self, guess_fit: float | None) -> bool:
        """Does the guess keep the scan on the walls (``hold_fit_ratio`` of the recent accepted
        guesses' median)? Then a scan without a fix is no sign of being lost."""
        ratio = self.config.hold_fit_ratio
        if ratio is None or guess_fit is None or len(self.guesses) < MIN_HISTORY:
            return False
        return guess_fit >= ratio * statistics.median(self.guesses)

    def worse_than_usual(self, guess_fit: float, fix_fit: float | None) -> bool:
        """Does the scan fit worse than usual: at the guess when no fix was used, at the fix
        (``fix_fit``) when one was (two lines matched to the wrong walls after a slip can pass
        the gates and still leave the scan off the walls)?"""
        if len(self.guesses) < MIN_HISTORY:
            return False
        if fix_fit is None:
            return not self.guess_holds(guess_fit)
        if not self.fixes:  # no fix used yet: nothing says how well one usually fits
            return False
        ratio = self.config.hold_fit_ratio or 1.0
        return fix_fit < ratio * statistics.median(self.fixes)

    def fix_gains(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...],
                  guess_fit: float | None, fraction: float | None = None) -> bool:
        """Does a fix that the matcher could not vouch for (one line, or lines that disagree) put
        ``min_fit_gain`` more of the scan's points on walls than the guess (``guess_fit``)?
        ``fraction``: the fix's own fraction on walls, if the caller has it."""
        gain = self.config.min_fit_gain
        if gain is None or guess_fit is None or len(points) == 0:
            return False
        if fraction is None:
            fraction = self.fraction(pose, points, kinds)
        if fraction < guess_fit + gain:
            return False
        self.counts["fixes_by_fit"] += 1
        return True

    def fix_fits(self, pose: NDArray, points: NDArray, kinds: tuple[str, ...] = ("wall",),
                 guess_fit: float | None = None, fraction: float | None = None) -> bool:
        """Does a tracking fix put the scan on the map's walls about as well as recent fixes did,
        and about as well as the guess it corrects (``guess_fit``, its fraction on walls)?

        The fraction of ``points`` (robot frame) within the global matcher's inlier distance of
        a wall at ``pose`` is compared with the median of the last ``fit_window`` fixes that
        passed: below ``misfit_ratio`` times that the fix is a misfit (the robot is not where the
        filter thinks, e.g. kidnapped). Relative, so that clutter and unmapped furniture, which
        lower every fix's fraction alike, do not make good fixes misfits. With ``max_fit_loss``
        set, a fix whose fraction is below ``guess_fit`` by more than that is a misfit too: it
        moved the scan off walls that the guess had it on (a wrong correspondence).
        ``fraction``: the fix's own fraction on walls, if the caller has it."""
        loss = self.config.max_fit_loss if guess_fit is not None else None
        if len(points) == 0:
            return True
        if fraction is None:
            fraction = self.fraction(pose, points, kinds)
        if loss is not None and guess_fit is not None and fraction < guess_fit - loss:
            self.counts["fit_losses"] += 1
            return False
        self.fixes.append(fraction)
        if self.config.misfit_ratio <= 0.0:
            return True
        used = self.used
        if (len(used) >= MIN_HISTORY
                and fraction < self.config.misfit_ratio * statistics.median(used)):
            self.counts["misfits"] += 1
            return False
        used.append(fraction)
        return True

    def typical_fix(self) -> float | None:
        """The median fit of the recent fixes that passed (None before the first)."""
        return statistics.median(self.fixes) if self.fixes else None

    def least_right(self, quantile: float) -> float | None:
        """The fit that all but ``quantile`` of the accepted scans reached (None before
        ``MIN_QUANTILE_HISTORY`` of them): a pose taken must fit at least as well as tracking
        usually did."""
        if len(self.tracked) < MIN_QUANTILE_HISTORY:
            return None
        return float(np.quantile(np.fromiter(self.tracked, float), quantile))


def _reach(points: NDArray) -> float:
    """The range of the farthest of (non-empty) robot-frame ``points``."""
    return float(np.max(np.hypot(points[:, 0], points[:, 1])))


def _fill(row: NDArray[np.float64], on: NDArray[np.bool_], seen: NDArray[np.bool_]) -> None:
    """One pose's shares: on a wall seen directly, seen through a wall, and neither."""
    row[0] = np.mean(on & seen)
    row[1] = 1.0 - np.mean(seen)
    row[2] = 1.0 - row[0] - row[1]
