"""The object and task catalogue is data: the default file, a lab's own extending it, and clear errors."""
from pathlib import Path

import pytest
from vla_common.catalogue import DEFAULT_PATH, CatalogueError, default_catalogue, load_catalogue
from vla_common.layout import random_layout, validate_layout
from vla_common.objects import OBJECT_CLASSES
from vla_common.tasks import parse_task, task_layout

ROOT = Path(__file__).resolve().parents[3]
SPAM = ROOT / "test" / "data" / "spam_catalogue.yaml"


def write(tmp_path, text: str, name: str = "c.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_default_catalogue_is_the_papers_five_objects():
    cat = default_catalogue()
    assert cat.classes == ("bread", "soda_can", "milk_carton", "glass_bottle", "cereal_box") == OBJECT_CLASSES
    assert [t.name for t in cat.task_set("base")] == [
        "bread/push_east", "soda_can/push_south", "milk_carton/push_south_west", "glass_bottle/push_west"]
    assert [t.action for t in cat.task_set("cereal_box")] == ["push_south", "push_south_east", "circle"]
    assert cat.sources == (str(DEFAULT_PATH),)


def test_a_lab_catalogue_adds_an_object_without_code():
    cat = load_catalogue(SPAM)
    assert cat.classes[:5] == OBJECT_CLASSES and cat.classes[5] == "spam"  # old indices kept
    spec = cat.spec("spam")
    assert spec.shape == "box" and spec.size == (0.10, 0.06, 0.08)
    task = cat.task("spam:push-south-east")
    assert task.name == "spam/push_south_east" and task.direction == "south_east" and task.distance == 0.15
    assert parse_task("spam/push_south_east", cat) is task
    assert cat.task_set("new") == [task] and len(cat.task_set("base")) == 4
    layout = task_layout(task, __import__("numpy").random.default_rng(3), n_objects=3, catalogue=cat)
    assert layout[0].class_id == "spam" and len(layout) == 3
    assert validate_layout(layout, cat) and random_layout(__import__("numpy").random.default_rng(0), 5,
                                                          catalogue=cat)
    with pytest.raises(CatalogueError, match="unknown object class 'spam'"):
        parse_task("spam/push_south_east")  # not in the default catalogue


def test_unknown_class_and_task_errors_list_the_known_ones_and_where():
    cat = load_catalogue(SPAM)
    with pytest.raises(CatalogueError) as err:
        cat.task("toaster/push_east")
    assert "known classes" in str(err.value) and "'spam'" in str(err.value) and str(SPAM) in str(err.value)
    with pytest.raises(CatalogueError, match=r"spam has no task 'circle'; its tasks are \['push_south_east'"):
        cat.task("spam/circle")
    with pytest.raises(CatalogueError, match="detector has classes"):
        cat.check_classes(["bread", "teapot"], "detector")


def test_replacing_catalogue_and_task_options(tmp_path):
    path = write(tmp_path, "objects:\n  cup:\n    shape: cylinder\n    size: [0.04, 0.04, 0.1]\n"
                           "    rgba: [1, 1, 1, 1]\n    mass: 0.2\n    friction: 0.5\n"
                           "    tasks: [{push_north: {distance: 0.2}}, circle]\n")
    cat = load_catalogue(path)
    assert cat.classes == ("cup",) and cat.task("cup/push_north").distance == 0.2


@pytest.mark.parametrize("text, message", [
    ("[]\n", "a mapping with an 'objects' mapping"),
    ("objects: {a: {shape: cone, size: [1, 1, 1], rgba: [1, 1, 1, 1], mass: 1, friction: 1}}\n",
     "shape must be one of"),
    ("objects: {a: {shape: box, size: [0.1, 0.1], rgba: [1, 1, 1, 1], mass: 1, friction: 1}}\n",
     "objects.a.size must be a list of 3 finite numbers"),
    ("objects: {a: {shape: box, size: [0.1, 0.1, 0.1], rgba: [1, 1, 1, 1], mass: 1, friction: 1, "
     "tasks: [push_up]}}\n",
     r"objects.a.tasks\[0\]: unknown task; a task is 'circle', 'lift', push_<direction> or pick_place_"),
    ("objects: {a: {shape: box, size: [0.1, 0.1, 0.1]}}\n", "lacks"),
    ("objects: {}\ntask_sets: {x: [a/push_east]}\n", r"task_sets.x\[0\] names a task that no object defines"),
    ("objects: {}\nextra: 1\n", "unknown key 'extra'; expected extends, objects, task_sets"),
    ("extends: c.yaml\nobjects: {}\n", "loops back"),
    ("objects: [\n", "invalid YAML"),
])
def test_bad_catalogues_are_refused_with_the_reason(tmp_path, text, message):
    with pytest.raises(CatalogueError, match=message):
        load_catalogue(write(tmp_path, text))


def test_a_missing_file_is_refused():
    with pytest.raises(CatalogueError, match="cannot read catalogue"):
        load_catalogue("/no/such/catalogue.yaml")
