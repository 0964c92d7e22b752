"""The map: YAML contract and its errors, collinear merging, reference points, visibility, index."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from houghloc import MapError, SegmentMap
from houghloc.geometry import ray_segment_distances
from houghloc.visibility import first_hits_and_clearance, ray_directions
from tests.conftest import MAPS


def write(tmp_path, text: str):
    p = tmp_path / "m.yaml"
    p.write_text(text)
    return p


def test_shipped_maps_load(robocup: SegmentMap, office: SegmentMap) -> None:
    assert len(robocup) == 15 and set(robocup.kinds) == {"wall", "line"}
    assert int((robocup.kinds == "line").sum()) == 3  # b, c, d
    assert len(office) >= 25
    # the office has a wall that is not axis-aligned
    angles = np.degrees(office.line_alpha) % 90
    assert np.any((angles > 5) & (angles < 85))


def test_collinear_segments_share_one_line(robocup: SegmentMap) -> None:
    idx = {sid: i for i, sid in enumerate(robocup.ids)}
    assert robocup.line_of_segment[idx["e1"]] == robocup.line_of_segment[idx["e2"]]
    assert robocup.line_of_segment[idx["g1"]] == robocup.line_of_segment[idx["g2"]]
    assert robocup.line_of_segment[idx["a"]] != robocup.line_of_segment[idx["f"]]
    # the two pieces keep their own extents (the goal mouth stays open)
    e1, e2 = idx["e1"], idx["e2"]
    gaps = sorted([(robocup.seg_s0[e1], robocup.seg_s1[e1]), (robocup.seg_s0[e2],
                                                               robocup.seg_s1[e2])])
    assert gaps[1][0] - gaps[0][1] == pytest.approx(2.0)


def test_references_by_hand() -> None:
    m = SegmentMap([[0, 0], [0, 0]], [[10, 0], [0, 10]])
    refs = m.references((2.0, 3.0, math.radians(30)), max_range=20)
    by_line = dict(zip(refs.line.tolist(), zip(refs.theta, refs.rho, strict=True), strict=True))
    # wall y = 0 seen from (2, 3): 3 m away, normal pointing to −y: world 270°, robot 240°
    theta, rho = by_line[m.line_of_segment[0]]
    assert rho == pytest.approx(3.0) and math.degrees(theta) == pytest.approx(240.0)
    theta, rho = by_line[m.line_of_segment[1]]
    assert rho == pytest.approx(2.0) and math.degrees(theta) == pytest.approx(150.0)


def test_hidden_wall_is_not_a_reference() -> None:
    # a long wall at y = 2 hides the parallel wall at y = 4 from the origin
    m = SegmentMap([[-50, 2], [-50, 4]], [[50, 2], [50, 4]])
    refs = m.references((0.0, 0.0, 0.0), max_range=10)
    assert refs.rho.tolist() == pytest.approx([2.0])
    # painted lines are never hidden and never hide
    m2 = SegmentMap([[-50, 2], [-50, 4]], [[50, 2], [50, 4]], kinds=["line", "wall"])
    refs2 = m2.references((0.0, 0.0, 0.0), max_range=10, kinds=("wall", "line"))
    assert sorted(refs2.rho.tolist()) == pytest.approx([2.0, 4.0])
    assert len(m2.references((0.0, 0.0, 0.0), max_range=10)) == 1  # laser: walls only


def test_spatial_index_returns_only_nearby_segments(office: SegmentMap) -> None:
    near = office.segments_near((1.0, 1.0), 2.0)
    far = office.segments_near((25.0, 11.0), 2.0)
    assert len(near) and len(far) and not set(near) & set(far)
    mids = (office.starts + office.ends) / 2
    assert np.all(np.linalg.norm(mids[near] - [1.0, 1.0], axis=1) < 2.0 + 14.0)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_rays=st.sampled_from([8, 90, 180, 360]),
       max_range=st.floats(0.5, 40.0), where=st.sampled_from(["free", "endpoint", "on"]))
def test_first_hits_only_try_the_rays_a_segment_spans(seed, n_rays, max_range, where) -> None:
    """Trying each segment only on the rays within its angular extent gives the segments that
    trying every ray on every segment does (and on a tie, the same one)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    starts = rng.uniform(-10, 10, (n, 2))
    ends = starts + rng.normal(0, 3, (n, 2))
    if seed % 3 == 0:  # walls on a grid: parallel rays, shared corners, ties
        starts, ends = np.round(starts), np.round(ends)
    origin = {"free": rng.uniform(-10, 10, 2), "endpoint": starts[0].copy(),
              "on": 0.5 * (starts[0] + ends[0])}[where]
    phi = np.linspace(0.0, 2 * math.pi, n_rays, endpoint=False)
    t = ray_segment_distances(origin, np.column_stack((np.cos(phi), np.sin(phi))), starts, ends)
    t[t > max_range] = np.inf
    expected = np.zeros(n, bool)
    first = np.argmin(t, axis=1)  # the first of equal distances, as the sweep keeps
    expected[first[np.isfinite(t.min(axis=1))]] = True
    hit, _ = first_hits_and_clearance(ray_directions(n_rays), max_range, starts, ends,
                                       float(origin[0]), float(origin[1]))
    assert np.array_equal(hit, expected)


@settings(max_examples=100, deadline=None)
@given(x=st.floats(-10, 40), y=st.floats(-10, 25), radius=st.floats(0.0, 30.0))
def test_segments_near_are_those_with_an_index_point_in_reach(office: SegmentMap, x, y,
                                                              radius) -> None:
    spacing = office._index_spacing
    reach = radius + spacing
    expected = []
    for j, (a, b) in enumerate(zip(office.starts, office.ends, strict=True)):
        k = max(2, math.ceil(np.linalg.norm(b - a) / spacing) + 1)
        samples = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
        if (((samples - [x, y]) ** 2).sum(axis=1) <= reach**2).any():
            expected.append(j)
    assert office.segments_near((x, y), radius).tolist() == expected


def test_round_trip_yaml(tmp_path, office: SegmentMap) -> None:
    office.to_yaml(tmp_path / "o.yaml")
    again = SegmentMap.from_yaml(tmp_path / "o.yaml")
    assert again.ids == office.ids
    np.testing.assert_allclose(again.starts, office.starts)


@pytest.mark.parametrize(("text", "expected"), [
    ("", "empty"),
    ("name: x\n", "'segments' is missing"),
    ("segments: []\n", "no segments"),
    ("segments: [1, 2]\n", "segment #0"),
    ("segments:\n  - {id: w0, from: [0, 0]}\n", "segment #0 (id 'w0'): 'to' is missing"),
    ("segments:\n  - {id: w0, from: [0, 0], to: [1, 1]}\n  - {id: w1, from: [0, x], to: [1, 1]}\n",
     "segment #1 (id 'w1'): from"),
    ("segments:\n  - {id: w0, kind: door, from: [0, 0], to: [1, 1]}\n", "kind"),
    ("segments:\n  - {id: w0, from: [0, 0], to: [0, 0]}\n", "'from' equals 'to'"),
    ("segments:\n  - {id: w0, from: [0, 0], to: [1, 0]}\n  - {id: w0, from: [0, 1], to: [1, 1]}\n",
     "duplicate id"),
    ("segments:\n  - {id: w0, from: [0, 0], to: [.nan, 0]}\n", "finite"),
    ("segments: {a: 1}\n", "segments"),
    ("- just\n- a list\n", "expected a mapping"),
    ("segments: [\n", "not valid YAML"),
])
def test_bad_map_files_name_file_entry_and_problem(tmp_path, text: str, expected: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(MapError) as err:
        SegmentMap.from_yaml(path)
    assert str(path) in str(err.value)
    assert expected in str(err.value)


def test_missing_map_file(tmp_path) -> None:
    with pytest.raises(MapError, match="file not found"):
        SegmentMap.from_yaml(tmp_path / "nope.yaml")


def test_kind_defaults_to_wall(tmp_path) -> None:
    m = SegmentMap.from_yaml(write(tmp_path, "segments:\n  - {from: [0, 0], to: [1, 0]}\n"))
    assert m.kinds.tolist() == ["wall"] and m.ids == ["s0"]


def test_maps_directory_has_the_contract_maps() -> None:
    assert (MAPS / "robocup.yaml").exists() and (MAPS / "office.yaml").exists()
