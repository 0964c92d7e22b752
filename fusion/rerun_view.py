"""How the recording looks: the colours (one per map line, a neutral one for the walls), the
styles logged once per entity, the geometry drawn (covariance ellipses, accumulator pixels) and
the default blueprint that lays the views out (readable on a 1600 × 1000 screen).

Entity paths (2D geometry already in map coordinates: rerun 0.41 has no 2D transform)::

    world/map/walls, world/map/lines          LineStrips2D, static: walls grey, painted lines
                                              white and thinner
    world/map/matched                         the walls of the map lines the scan matched, each in
                                              its line's colour (that of the points on it)
    world/scan/points                         the scan at the estimated pose, each point in the
                                              colour of the map line its observed line matched;
                                              on an unmatched observed line light grey, else grey
    world/scan/<sensor>/points                the same for every sensor after the first one seen
    world/robot/estimate                      Arrows2D, coloured by the measurement's status
    world/robot/covariance                    95 % ellipse of the x-y covariance (LineStrips2D)
    world/robot/truth                         Arrows2D, when ground truth is logged
    world/path/{estimate,odometry,truth}/<k>  the paths, in pieces (see below); odometry is
                                              est₀ ⊕ (odom₀⁻¹ ⊕ odomₖ), anchored at the first scan;
                                              the newest piece labelled with the path's name
    hough/accumulator                         DepthImage of the votes, viridis colour map (8 bits
                                              when the first scan has ≤ 255 points, else 16)
    hough/peaks, hough/references             Points2D in accumulator pixels (references labelled
                                              with their segment ids)
    hough/matches                             LineStrips2D, observed line → its reference point
    metrics/innovation/{x,y,theta}, metrics/nis, metrics/sigma/{x,y,theta}, metrics/matches,
    metrics/error/{position,heading}          Scalars (errors: truth interpolated at the scan)
    metrics/along_corridor                    Scalars (m a corridor fix was moved along it)
    metrics/localized                         Scalars (the probability that the pose is right,
                                              fusion.integrity)
    log/state                                 TextLog: the ambiguity manager's state and reason
    log/scan                                  TextLog: why a scan was not used (not "accepted")
    global/hypotheses                         Arrows2D with the scores as labels
"""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import ArrayLike, NDArray

from fusion.status import ScanStatus
from houghloc.geometry import TWO_PI
from houghloc.jit import njit

MAX_ELLIPSE_RADIUS = 20.0  # m; an unobserved direction would otherwise zoom the view out to nothing
ARROW_LENGTH = 0.5  # m
CHI2_95_2DOF = 5.991464547107979  # χ²(2) quantile of the 95 % ellipse
POINT_RADIUS = 0.03  # m
PAINTED = (235, 235, 235, 255)
OBSERVED_UNMATCHED = (170, 170, 170, 255)
UNMATCHED = (100, 100, 100, 255)
WALL_COLOUR = (120, 130, 150, 255)  # every wall; the matched ones are drawn over in their colour
# the time series: x, y, θ in the usual red, green, blue; one-line series in a neutral colour
SERIES_COLOURS = {"x": (230, 80, 70, 255), "y": (90, 190, 90, 255), "theta": (80, 140, 240, 255),
                  "position": (230, 80, 70, 255), "heading": (80, 140, 240, 255)}
SERIES_COLOUR = (220, 220, 220, 255)
SERIES_NAMES = {"error/position": "position (m)", "error/heading": "heading (°)",
                "sigma/x": "σx (m)", "sigma/y": "σy (m)", "sigma/theta": "σθ (°)",
                "innovation/x": "x (m)", "innovation/y": "y (m)", "innovation/theta": "θ (°)",
                "nis": "NIS", "matches": "lines matched",
                "along_corridor": "placed along the corridor (m)"}
STATUS_COLOURS = {
    ScanStatus.ACCEPTED: (60, 200, 90, 255),
    ScanStatus.REJECTED: (230, 60, 50, 255),
    ScanStatus.AMBIGUOUS: (250, 160, 30, 255),
    ScanStatus.NO_FIX: (150, 150, 150, 255),
    ScanStatus.DROPPED: (140, 40, 40, 255),
    ScanStatus.INVALID: (140, 40, 40, 255),
}
STATE_LEVELS = {"tracking": "INFO", "collecting": "WARN", "relocalizing": "WARN", "lost": "ERROR"}
ODOMETRY_COLOUR = (200, 120, 255, 255)
TRUTH_COLOUR = (80, 200, 255, 255)
ESTIMATE_COLOUR = (60, 200, 90, 255)
_UNIT_CIRCLE = np.vstack((np.cos(np.linspace(0.0, 2.0 * np.pi, 37)),
                          np.sin(np.linspace(0.0, 2.0 * np.pi, 37))))


# ------------------------------------------------------------------------------- colours
def line_palette(n: int) -> NDArray[np.uint8]:
    """``n`` RGBA colours, one per map line id; line k's colour does not depend on ``n``.

    Hues step by the golden ratio, so neighbouring ids get far-apart hues.
    """
    h = (np.arange(n) * 0.6180339887498949) % 1.0
    s, v = 0.75, 0.95
    i = np.floor(h * 6.0).astype(int) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    vv = np.full(n, v)
    pp = np.full(n, p)
    r = np.choose(i, [vv, q, pp, pp, t, vv])
    g = np.choose(i, [t, vv, vv, q, pp, pp])
    b = np.choose(i, [pp, pp, t, vv, vv, q])
    rgba = np.column_stack((r, g, b, np.ones(n))) * 255.0
    return np.round(rgba).astype(np.uint8)


class LineColours:
    """Colour table indexed by map line id; row −1 is 'unmatched', row −2 'on an unmatched line'.

    Built once from the map (painted lines white); grows by the palette for ids it has not seen
    (a logger used without ``log_map``).
    """

    def __init__(self) -> None:
        self.painted = np.zeros(0, dtype=bool)
        self.names = np.zeros(0, dtype=object)
        self.table = self._build(0)

    def set_map(self, painted: NDArray[np.bool_], names: list[str]) -> None:
        self.painted = painted
        self.names = np.asarray(names, dtype=object)
        self.table = self._build(len(painted))

    def _build(self, n: int) -> NDArray[np.uint8]:
        rows = line_palette(n)
        painted = np.zeros(n, dtype=bool)
        painted[: len(self.painted)] = self.painted[:n]
        rows[painted] = PAINTED
        return np.vstack((rows, [OBSERVED_UNMATCHED, UNMATCHED])).astype(np.uint8)

    @property
    def n_lines(self) -> int:
        return len(self.table) - 2

    def ensure(self, ids: NDArray[np.intp]) -> None:
        if len(ids) and int(ids.max()) >= self.n_lines:
            self.table = self._build(int(ids.max()) + 1)

    def label(self, ids: NDArray[np.intp]) -> list[str]:
        known = len(self.names)
        if len(ids) == 0 or int(ids.max()) < known:  # the usual case: lines of the logged map
            return self.names[ids].tolist()  # set_map's names are strings
        return [str(self.names[i]) if i < known else f"line {i}" for i in ids.tolist()]


@njit
def point_rows(members: NDArray[np.bool_], matched_lines: NDArray[np.int64],
               map_lines: NDArray[np.int64]) -> NDArray[np.int64]:
    """Each point's colour-table row: the map line of the first match (in ``matched_lines``,
    the scan's line of each match, ``map_lines`` its map line) whose line holds the point
    (``members``, points × lines), else −2 on a line, else −1. One pass, compiled: it runs on
    every scan of a recording."""
    rows = np.full(members.shape[0], -1, np.int64)
    for i in range(members.shape[0]):
        for m in range(matched_lines.shape[0]):
            if members[i, matched_lines[m]]:
                rows[i] = map_lines[m]
                break
        if rows[i] == -1:
            for j in range(members.shape[1]):
                if members[i, j]:
                    rows[i] = -2
                    break
    return rows


@njit
def batch_point_rows(members: NDArray[np.bool_], n_points: NDArray[np.int64],
                     n_lines: NDArray[np.int64], matched_lines: NDArray[np.int64],
                     map_lines: NDArray[np.int64], n_matches: NDArray[np.int64]
                     ) -> NDArray[np.int64]:
    """:func:`point_rows` of many scans in one call: scan s has ``n_points[s]`` points,
    ``n_lines[s]`` lines (its membership matrix flattened in ``members``, row-major, after the
    previous scans') and ``n_matches[s]`` matches (in ``matched_lines`` and ``map_lines``)."""
    rows = np.empty(n_points.sum(), np.int64)
    at_point, at_member, at_match = 0, 0, 0
    for s in range(n_points.shape[0]):
        n, k, m = n_points[s], n_lines[s], n_matches[s]
        rows[at_point:at_point + n] = point_rows(
            members[at_member:at_member + n * k].reshape((n, k)),
            matched_lines[at_match:at_match + m], map_lines[at_match:at_match + m])
        at_point, at_member, at_match = at_point + n, at_member + n * k, at_match + m
    return rows


# ------------------------------------------------------------------------------- geometry
def covariance_ellipse(xy: ArrayLike, cov_xy: ArrayLike,
                       chi2: float = CHI2_95_2DOF) -> NDArray[np.float64]:
    """Closed polyline (37×2) of the ellipse {p : (p−xy)ᵀ C⁻¹ (p−xy) = χ²}, semi-axes clamped;
    for stacks (xy n×2, C n×2×2), n such polylines (n×37×2)."""
    cov = np.asarray(cov_xy, dtype=float)
    # the symmetric 2×2 eigenproblem in closed form, for a whole batch at once: the
    # eigenvalues m ± d, the major axis at angle φ with tan 2φ = 2b / (a − c)
    a, c = cov[..., 0, 0], cov[..., 1, 1]
    b = 0.5 * (cov[..., 0, 1] + cov[..., 1, 0])
    m, d = 0.5 * (a + c), np.hypot(0.5 * (a - c), b)
    phi = 0.5 * np.arctan2(2.0 * b, a - c)
    major = np.minimum(np.sqrt(np.maximum(m + d, 0.0) * chi2), MAX_ELLIPSE_RADIUS)
    minor = np.minimum(np.sqrt(np.maximum(m - d, 0.0) * chi2), MAX_ELLIPSE_RADIUS)
    cp, sp = np.cos(phi)[..., None], np.sin(phi)[..., None]
    u, v = major[..., None] * _UNIT_CIRCLE[0], minor[..., None] * _UNIT_CIRCLE[1]
    centre = np.asarray(xy, dtype=float)[..., :2]
    return np.stack((cp * u - sp * v + centre[..., 0:1], sp * u + cp * v + centre[..., 1:2]),
                    axis=-1)


@njit
def hough_marks(theta_step: float, rho_step: float, rho_min: float, line_theta: NDArray,
                line_rho: NDArray, ref_theta: NDArray, ref_rho: NDArray, match_line: NDArray,
                match_ref: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """A scan's marks on the accumulator image, in pixel coordinates (u = (ρ − ρ_min)/δρ, the
    column; v = θ/δθ + ½, the row): its lines' peaks, the map's references, and a segment from
    each match's peak to its reference (match k pairs line ``match_line[k]`` with reference
    ``match_ref[k]``). θ is put in its own cell's row, [−δθ/2, 2π − δθ/2): cell i is centred on
    iδθ, so cell 0 straddles θ = 0 and θ just below 2π is drawn in it. A segment's reference
    end takes the θ nearest its peak's, so a pair across θ = 0 ≡ 2π is drawn short (its end
    may then lie just outside the image). One compiled pass: it runs on every scan."""
    peaks = np.empty((line_theta.shape[0], 2))
    for i in range(line_theta.shape[0]):
        peaks[i, 0] = _column(line_rho[i], rho_step, rho_min)
        peaks[i, 1] = _row(_own_row(line_theta[i], theta_step), theta_step)
    refs = np.empty((ref_theta.shape[0], 2))
    for i in range(ref_theta.shape[0]):
        refs[i, 0] = _column(ref_rho[i], rho_step, rho_min)
        refs[i, 1] = _row(_own_row(ref_theta[i], theta_step), theta_step)
    ends = np.empty((match_line.shape[0], 2, 2))
    for k in range(match_line.shape[0]):
        line, ref = match_line[k], match_ref[k]
        theta_line = _own_row(line_theta[line], theta_step)
        theta_ref = theta_line + ((ref_theta[ref] - theta_line + np.pi) % TWO_PI - np.pi)
        ends[k, 0, 0], ends[k, 0, 1] = peaks[line, 0], peaks[line, 1]
        ends[k, 1, 0] = _column(ref_rho[ref], rho_step, rho_min)
        ends[k, 1, 1] = _row(theta_ref, theta_step)
    return peaks, refs, ends


@njit
def _own_row(theta: float, theta_step: float) -> float:
    """θ in [−δθ/2, 2π − δθ/2): θ cell i is centred on iδθ, so cell 0 straddles θ = 0."""
    half = 0.5 * theta_step
    return (theta + half) % TWO_PI - half


@njit
def _row(theta: float, theta_step: float) -> float:
    return theta / theta_step + 0.5


@njit
def _column(rho: float, rho_step: float, rho_min: float) -> float:
    return (rho - rho_min) / rho_step


# ------------------------------------------------------------------------------- blueprint
def default_blueprint() -> rrb.Blueprint:
    """The world (map, scan, robot, paths, hypotheses) over the manager's log, beside the Hough
    accumulator, the errors and, in tabs, σ, the innovation, the NIS and the matches: each plot
    a full column wide, readable at 1600 × 1000 with the side panels collapsed."""
    world = rrb.Spatial2DView(name="World: walls grey, matched walls in their points' colour",
                              origin="/", contents=["+ world/**", "+ global/**"])
    hough = rrb.Spatial2DView(name="Hough accumulator (rows θ, columns ρ)", origin="hough")
    legend = rrb.PlotLegend(corner=rrb.components.Corner2D.LeftTop, visible=True)
    alone = rrb.PlotLegend(visible=False)  # one series: the title says what it is

    def series(name: str, origin: str, plot_legend: rrb.PlotLegend) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=name, origin=origin, plot_legend=plot_legend)

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, rrb.TextLogView(name="Manager and scans", origin="log"),
                         row_shares=[4, 1]),
            rrb.Vertical(
                hough,
                series("Error against the reference", "metrics/error", legend),
                rrb.Tabs(series("σ of the estimate", "metrics/sigma", legend),
                         series("Innovation", "metrics/innovation", legend),
                         series("NIS (normalised innovation squared)", "metrics/nis", alone),
                         series("Lines matched", "metrics/matches", alone),
                         series("Corridor fixes placed along the corridor",
                                "metrics/along_corridor", alone),
                         series("Probability that the pose is right", "metrics/localized",
                                alone)),
                row_shares=[2, 1, 1],
            ),
            column_shares=[11, 9],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="time", state="collapsed"),
    )


def entity_styles() -> dict[str, Any]:
    """What does not change from row to row, logged once per entity as static data."""
    return {
        "points": rr.Points2D.from_fields(radii=POINT_RADIUS, draw_order=3.0),
        "world/robot/estimate": rr.Arrows2D.from_fields(radii=0.04, draw_order=5.0,
                                                        show_labels=False),
        "world/robot/covariance": rr.LineStrips2D.from_fields(radii=0.015, draw_order=4.0),
        "world/robot/truth": rr.Arrows2D.from_fields(radii=0.03, draw_order=4.5,
                                                     colors=TRUTH_COLOUR),
        "hough/peaks": rr.Points2D.from_fields(radii=1.2, draw_order=2.0),
        "hough/references": rr.Points2D.from_fields(radii=0.8, draw_order=3.0,
                                                    show_labels=False),
        "hough/matches": rr.LineStrips2D.from_fields(radii=0.3, draw_order=1.0),
    }
PATH_COLOURS = {"estimate": ESTIMATE_COLOUR, "odometry": ODOMETRY_COLOUR, "truth": TRUTH_COLOUR}


def heading_vector(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """The arrows drawing poses (n×3) or one pose (3,): ``ARROW_LENGTH`` along each heading."""
    theta = np.asarray(poses, dtype=float).reshape(-1, 3)[:, 2]
    return ARROW_LENGTH * np.column_stack((np.cos(theta), np.sin(theta)))
