"""Task definitions, parsing, success criterion and task-aware layouts."""
import math

import numpy as np
import pytest
from vla_common.catalogue import CatalogueError, default_catalogue, load_catalogue
from vla_common.layout import overlap
from vla_common.objects import OBJECT_CLASSES, OBJECT_SPECS, ObjectPose, compass_vector
from vla_common.tasks import (
    BASE_TASKS,
    PUSH_REGION_X,
    TASKS,
    UNSEEN_TASKS,
    TaskSpec,
    circle_sweep_deg,
    parse_task,
    task_layout,
    task_success,
)


def test_task_table_matches_the_paper():
    assert BASE_TASKS == ["bread/push_east", "soda_can/push_south", "milk_carton/push_south_west",
                          "glass_bottle/push_west"]
    assert UNSEEN_TASKS == ["cereal_box/push_south", "cereal_box/push_south_east", "cereal_box/circle"]
    hand = [t.name for t in default_catalogue().task_set("hand")]
    assert hand == ["soda_can/lift", "soda_can/pick_place_west", "glass_bottle/pick_place_west"]
    assert set(TASKS) == set(BASE_TASKS + UNSEEN_TASKS + hand)
    t = TASKS["milk_carton/push_south_west"]
    assert (t.object_class, t.kind, t.direction, t.distance) == ("milk_carton", "push", "south_west", 0.15)
    circle = TASKS["cereal_box/circle"]
    assert circle.kind == "circle" and circle.direction is None


def test_compass_convention():
    np.testing.assert_allclose(compass_vector("north"), [1, 0])
    np.testing.assert_allclose(compass_vector("east"), [0, -1])
    np.testing.assert_allclose(compass_vector("south-west"), [-math.sqrt(0.5), math.sqrt(0.5)])


@pytest.mark.parametrize("text", ["bread:push_east", "bread/push_east", " bread/push_east "])
def test_parse_task_separators(text):
    assert parse_task(text) is TASKS["bread/push_east"]


def test_parse_task_gives_the_catalogue_task():
    spec = parse_task("milk_carton:push_south_west")
    assert spec == TaskSpec("milk_carton/push_south_west", "milk_carton", "push", "south_west")
    assert parse_task("cereal_box/circle").kind == "circle"
    assert parse_task(spec) is spec  # a parsed task travels as itself


@pytest.mark.parametrize("text, message", [
    ("toaster/push_east", "unknown object class"),
    ("bread/push_up", "has no task 'push_up'"),
    ("soda_can:push_north_west", "its tasks are \\['push_south', 'lift', 'pick_place_west'\\]"),
    ("bread", "must look like"),
    ("bread/push_east/x", "must look like"),
    (42, "must be a string"),
])
def test_parse_task_errors(text, message):
    with pytest.raises(ValueError, match=message):
        parse_task(text)


def _moved(start, dx, dy):
    return ObjectPose(start.class_id, start.x + dx, start.y + dy, start.yaw)


def test_push_success_criterion():
    task = TASKS["bread/push_east"]  # east = -y
    s = ObjectPose("bread", 0.5, 0.1, 0.0)
    ok, disp, ang = task_success(task, s, _moved(s, 0.0, -0.12))
    assert ok and disp == pytest.approx(0.12) and ang == pytest.approx(0.0, abs=1e-6)
    assert not task_success(task, s, _moved(s, 0.0, -0.09))[0]           # too short
    off = 0.12 * np.array([math.sin(math.radians(35)), -math.cos(math.radians(35))])
    ok, _, ang = task_success(task, s, _moved(s, *off))
    assert not ok and ang == pytest.approx(35.0)                          # too far off direction
    off = 0.12 * np.array([math.sin(math.radians(25)), -math.cos(math.radians(25))])
    assert task_success(task, s, _moved(s, *off))[0]
    assert not task_success(task, s, _moved(s, 0.0, 0.2))[0]              # wrong way
    assert not task_success(task, s, s)[0]
    assert task_success("bread:push_east", s, _moved(s, 0.0, -0.15))[0]


def test_circle_success_criterion():
    task = TASKS["cereal_box/circle"]
    s = ObjectPose("cereal_box", 0.5, 0.0, 0.0)
    ok, disp, ang = task_success(task, s, _moved(s, 0.01, 0.0))
    assert ok and math.isnan(ang)
    assert not task_success(task, s, _moved(s, 0.05, 0.0))[0]


def test_a_circle_needs_the_arm_to_go_round():
    """An unmoved object alone is not a circle: an arm that never moved leaves it unmoved too."""
    task = TASKS["cereal_box/circle"]
    s = ObjectPose("cereal_box", 0.5, 0.1, 0.0)

    def arc(deg):
        a = np.radians(np.linspace(40.0, 40.0 + deg, 50))
        return np.column_stack([0.5 + 0.15 * np.cos(a), 0.1 + 0.15 * np.sin(a)])

    ok, _, shortfall = task_success(task, s, _moved(s, 0.01, 0.0), arc(350.0))
    assert ok and shortfall == 0.0
    ok, _, shortfall = task_success(task, s, _moved(s, 0.01, 0.0), arc(180.0))
    assert not ok and shortfall == pytest.approx(150.0)
    assert not task_success(task, s, s, np.tile([0.65, 0.1], (20, 1)))[0]  # the arm stayed put
    assert not task_success(task, s, _moved(s, 0.05, 0.0), arc(360.0))[0]  # went round, knocked it
    assert circle_sweep_deg(arc(720.0), (0.5, 0.1)) == pytest.approx(720.0)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_task_layouts(name):
    spec = TASKS[name]
    for seed in range(20):
        layout = task_layout(spec, np.random.default_rng(seed))
        assert layout[0].class_id == spec.object_class
        assert 1 <= len(layout) <= 4 and len({p.class_id for p in layout}) == len(layout)
        assert all(p.class_id in OBJECT_CLASSES for p in layout)
        for i, a in enumerate(layout):
            for b in layout[i + 1:]:
                assert not overlap(a, b, 0.0)
        target = layout[0]
        if spec.kind == "push":
            end = target.xy + spec.direction_vector * spec.distance
            assert PUSH_REGION_X[0] <= end[0] <= PUSH_REGION_X[1]
            for other in layout[1:]:  # nothing in the way of the push
                rel = other.xy - target.xy
                along = rel @ spec.direction_vector
                across = abs(rel @ np.array([-spec.direction_vector[1], spec.direction_vector[0]]))
                assert not (0.0 < along < spec.distance + 0.1 and across < 0.12)
    a = task_layout(spec, np.random.default_rng(3))
    b = task_layout(spec, np.random.default_rng(3))
    assert [(p.class_id, p.x, p.y, p.yaw) for p in a] == [(p.class_id, p.x, p.y, p.yaw) for p in b]


def test_footprint_circle_and_short_half_side():
    """The planner's pusher starts outside the footprint circle and pushes on by its slack over the
    short half-side: both must be right for boxes and cylinders."""
    bread, can = OBJECT_SPECS["bread"], OBJECT_SPECS["soda_can"]
    assert math.isclose(bread.footprint_radius, 0.5 * math.hypot(0.20, 0.10))
    assert math.isclose(bread.min_half_extent, 0.05)
    assert can.footprint_radius == can.min_half_extent == can.size[0]


def test_hand_tasks_success():
    from vla_common.tasks import held_lift_seconds, place_target, task_success

    lift = default_catalogue().task("soda_can/lift")
    start = ObjectPose("soda_can", 0.5, 0.0, 0.0, 0.061)
    t = np.arange(0.0, 5.0, 0.01)
    high = np.where((t > 1.0) & (t < 3.5), 0.09, 0.0)
    assert held_lift_seconds(t, high) == pytest.approx(2.49, abs=0.011)
    assert task_success(lift, start, start, lift=(t, high))[0]
    short = np.where((t > 1.0) & (t < 2.5), 0.09, 0.0)              # held 1.5 s
    assert not task_success(lift, start, start, lift=(t, short))[0]
    low = np.where((t > 1.0) & (t < 4.0), 0.04, 0.0)                # only 4 cm
    assert not task_success(lift, start, start, lift=(t, low))[0]
    gap = np.where((t > 1.0) & (t < 4.0) & (np.abs(t - 2.0) > 0.02), 0.09, 0.0)   # dropped for a moment
    assert not task_success(lift, start, start, lift=(t, gap))[0]
    assert not task_success(lift, start, start)[0]                   # no heights: never

    place = default_catalogue().task("soda_can/pick_place_west")
    target = place_target(place, start)
    assert target == pytest.approx([0.5, 0.15])
    near = ObjectPose("soda_can", 0.52, 0.18, 0.0, 0.061)
    ok, err, above = task_success(place, start, near)
    assert ok and err == pytest.approx(np.hypot(0.02, 0.03))
    assert not task_success(place, start, ObjectPose("soda_can", 0.5, 0.21, 0.0, 0.061))[0]   # 6 cm off
    assert not task_success(place, start, ObjectPose("soda_can", 0.5, 0.15, 0.0, 0.15))[0]    # still held
    assert not task_success(place, start, start)[0]


def test_hand_tasks_need_an_object_that_fits_the_open_hand(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("extends: default\nobjects:\n  tray: {shape: box, size: [0.2, 0.2, 0.03], "
                 "rgba: [1, 1, 1, 1], mass: 0.2, friction: 0.5, tasks: [lift]}\n")
    with pytest.raises(CatalogueError, match="fit the open hand"):
        load_catalogue(f)
    f.write_text("extends: default\nobjects:\n  cup: {shape: cylinder, size: [0.03, 0.03, 0.09], "
                 "rgba: [1, 1, 1, 1], mass: 0.2, friction: 0.5, tasks: [lift, {pick_place_north: "
                 "{distance: 0.1}}]}\n")
    cat = load_catalogue(f)
    t = cat.task("cup/pick_place_north")
    assert (t.kind, t.direction, t.distance, t.uses_hand) == ("pick_place", "north", 0.1, True)
    assert cat.task("cup/lift").distance == 0.10
    assert not cat.task("bread/push_east").uses_hand


def test_hand_task_layouts_keep_the_target_in_reach():
    from vla_common.tasks import GRASP_REGION_X, GRASP_REGION_Y, place_target

    spec = default_catalogue().task("soda_can/pick_place_west")
    rng = np.random.default_rng(4)
    for _ in range(30):
        layout = task_layout(spec, rng)
        target = place_target(spec, layout[0])
        assert GRASP_REGION_X[0] <= target[0] <= GRASP_REGION_X[1]
        assert GRASP_REGION_Y[0] <= target[1] <= GRASP_REGION_Y[1]


def test_spread_layouts_put_few_shot_demonstrations_at_the_regions_corners_and_centre():
    """Five demonstrations of a pick-and-place span the region (a fresh layout lies between them),
    each place target inside the region; random layouts from five seeds need not."""
    from vla_common.tasks import GRASP_REGION_X, GRASP_REGION_Y, SPREAD_JITTER, grasp_centre_region

    spec = default_catalogue().task("soda_can/pick_place_west")
    lo, hi = grasp_centre_region(spec)
    assert np.allclose(lo, [GRASP_REGION_X[0], GRASP_REGION_Y[0]])
    assert np.allclose(hi, [GRASP_REGION_X[1], GRASP_REGION_Y[1] - spec.distance])   # west: +y
    pts = np.array([task_layout(spec, np.random.default_rng(k), spread=k)[0].xy for k in range(5)])
    span = hi - lo
    corners = lo + np.array([[0.1, 0.1], [0.9, 0.1], [0.1, 0.9], [0.9, 0.9], [0.5, 0.5]]) * span
    assert np.all(np.abs(pts - corners) <= SPREAD_JITTER + 1e-9)
    assert np.all((pts >= lo) & (pts <= hi))
    assert np.all(pts.max(0) - pts.min(0) >= 0.75 * span)      # the demos cover the region
    with pytest.raises(ValueError, match="hand"):
        task_layout("bread/push_east", np.random.default_rng(0), spread=0)


def test_a_spread_margin_puts_the_corner_demonstrations_outside_the_region():
    """With a margin the spread points are the same fractions of the region grown by it: the corner
    demonstrations stand outside where layouts are drawn (a fresh layout inside their hull), the
    centre stays; 0 is the region itself; a negative or non-finite margin is refused."""
    from vla_common.tasks import SPREAD_JITTER, SPREAD_POINTS, grasp_centre_region

    spec = default_catalogue().task("glass_bottle/pick_place_west")
    lo, hi = grasp_centre_region(spec)
    margin = 0.06
    pts = np.array([task_layout(spec, np.random.default_rng(k), spread=k, spread_margin=margin)[0].xy
                    for k in range(5)])
    want = (lo - margin) + np.array(SPREAD_POINTS) * (hi - lo + 2 * margin)
    assert np.all(np.abs(pts - want) <= SPREAD_JITTER + 1e-9)
    corners = pts[:4]
    assert np.all((corners.min(0) < lo) & (corners.max(0) > hi))   # beyond the region on every side
    assert np.allclose(pts[4], (lo + hi) / 2, atol=SPREAD_JITTER)
    same = [task_layout(spec, np.random.default_rng(k), spread=k, spread_margin=0.0)[0].xy for k in range(5)]
    assert np.allclose(same, [task_layout(spec, np.random.default_rng(k), spread=k)[0].xy for k in range(5)])
    for bad in (-0.01, float("nan")):
        with pytest.raises(ValueError, match="spread_margin"):
            task_layout(spec, np.random.default_rng(0), spread=0, spread_margin=bad)
