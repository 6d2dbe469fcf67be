"""COCO JSON from labelling tools (CVAT, Label Studio, Roboflow) round-trips to YOLO with the right boxes."""

import json

import cv2
import numpy as np
import pytest
from vla_common.objects import OBJECT_CLASSES
from vla_detector_training.cli import main as cli_main
from vla_detector_training.coco import import_coco, parse_mapping
from vla_detector_training.dataset import DatasetError, label_path_for, load_data_config, load_split

W, H = 64, 48
# COCO boxes [x, y, w, h] from the top-left corner, in pixels (one overshoots the right edge by 1 px)
BOXES = {
    "frame_000.png": [(1, [10.5, 8.0, 15.0, 8.0]), (2, [40.0, 20.0, 6.0, 14.5])],
    "frame_001.png": [(2, [50.0, 30.0, 15.0, 10.0]), (3, [0.0, 0.0, 20.0, 30.0])],
    "frame_002.png": [],  # listed without annotations: a background image
}


def write_images(folder):
    folder.mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(BOXES):
        cv2.imwrite(str(folder / name), np.full((H, W, 3), 40 * (i + 1), np.uint8))


def cvat_coco(prefix=""):
    """The shape CVAT's "COCO 1.0" export writes (Label Studio's differs by the file_name prefix)."""
    doc = {
        "licenses": [{"name": "", "id": 0, "url": ""}],
        "info": {"contributor": "", "date_created": "", "description": "", "url": "", "version": "",
                 "year": ""},
        "categories": [{"id": 1, "name": "Bread", "supercategory": ""},
                       {"id": 2, "name": "soda_can", "supercategory": ""},
                       {"id": 3, "name": "person", "supercategory": ""}],
        "images": [], "annotations": [],
    }
    ann_id = 1
    for i, (name, boxes) in enumerate(BOXES.items(), start=1):
        doc["images"].append({"id": i, "width": W, "height": H, "file_name": prefix + name, "license": 0,
                              "flickr_url": "", "coco_url": "", "date_captured": 0})
        for cat, bbox in boxes:
            doc["annotations"].append({"id": ann_id, "image_id": i, "category_id": cat, "segmentation": [],
                                       "area": bbox[2] * bbox[3], "bbox": bbox, "iscrowd": 0,
                                       "attributes": {"occluded": False, "rotation": 0.0}})
            ann_id += 1
    return doc


def expected_centre_boxes(name):
    """YOLO's view of BOXES: centre and size in pixels, clipped to the image; 'person' left out."""
    out = []
    for cat, (x, y, w, h) in BOXES[name]:
        if cat == 3:
            continue
        x2 = min(x + w, W)
        cls = OBJECT_CLASSES.index({1: "bread", 2: "soda_can"}[cat])
        out.append((cls, (x + x2) / 2, y + h / 2, x2 - x, h))
    return out


@pytest.mark.parametrize("prefix", ["", "/data/upload/3/"])  # CVAT; Label Studio's upload path
def test_labelling_tool_coco_round_trips_to_yolo(tmp_path, prefix, caplog):
    write_images(tmp_path / "photos")
    (tmp_path / "annotations.json").write_text(json.dumps(cvat_coco(prefix)))
    report = import_coco(tmp_path / "annotations.json", tmp_path / "photos", tmp_path / "yolo",
                         OBJECT_CLASSES, parse_mapping(["Bread=bread", "person="]))
    assert (report.images, report.boxes, report.backgrounds) == (3, 3, 1)
    assert report.per_class == {"bread": 1, "soda_can": 2} and report.left_out == {"person": 1}
    cfg = load_data_config(tmp_path / "yolo")
    assert cfg.names == list(OBJECT_CLASSES) and list(cfg.splits) == ["train"]
    samples = load_split(cfg, "train")
    assert not caplog.records  # every image has its label file, the background an empty one
    assert [s.image_path.name for s in samples] == list(BOXES)
    for s in samples:
        got = [(b.class_index, b.cx, b.cy, b.w, b.h) for b in s.boxes]
        want = expected_centre_boxes(s.image_path.name)
        assert len(got) == len(want)
        for g, w in zip(got, want):
            assert g[0] == w[0] and g[1:] == pytest.approx(w[1:], abs=1e-3)
    assert label_path_for(samples[2].image_path).read_text() == ""
    assert all((tmp_path / "photos" / name).is_file() for name in BOXES)  # copied, never moved


def test_roboflow_placeholder_category_and_reimport(tmp_path):
    """Roboflow lists a supercategory placeholder (id 0) that no annotation uses; a second import of the
    same file into the same dataset changes nothing."""
    write_images(tmp_path / "photos")
    doc = cvat_coco()
    doc["categories"] = [{"id": 0, "name": "objects", "supercategory": "none"}] + [
        dict(c, name={1: "bread", 2: "soda_can", 3: "person"}[c["id"]]) for c in doc["categories"]]
    (tmp_path / "_annotations.coco.json").write_text(json.dumps(doc))
    args = ["import-coco", str(tmp_path / "_annotations.coco.json"), "--images", str(tmp_path / "photos"),
            "--out", str(tmp_path / "yolo"), "--map", "person="]
    assert cli_main(args) == 0
    first = (tmp_path / "yolo" / "labels" / "train" / "frame_000.txt").read_text()
    assert cli_main(args) == 0
    assert (tmp_path / "yolo" / "labels" / "train" / "frame_000.txt").read_text() == first


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda d: d["annotations"][1].update(bbox=[40, 20, -6, 14]), "annotations.json: annotation 2: bbox"),
        (lambda d: d["annotations"][2].update(bbox=[50, 30, 30, 10]), "annotation 3: bbox [50, 30, 30, 10] "
                                                                        "extends outside its 64x48 image"),
        (lambda d: d["annotations"][0].update(bbox="10 8 15 8"), "annotation 1: bbox must be"),
        (lambda d: d["annotations"][0].update(image_id=99), "annotation 1: image_id 99 is not in 'images'"),
        (lambda d: d["annotations"][0].update(category_id=7), "annotation 1: category_id 7"),
        (lambda d: d["images"][1].update(file_name="lost.png"), "image 2 ('lost.png'): not found"),
        (lambda d: d["images"][0].update(width=640), "image 1 (frame_000.png): listed as 640x48"),
        (lambda d: None, "category 3 'person' maps to none of our classes"),
    ],
)
def test_bad_annotations_are_named_by_file_and_id(tmp_path, change, message, capsys):
    write_images(tmp_path / "photos")
    doc = cvat_coco()
    maps = ["Bread=bread"] + (["person="] if "'person'" not in message else [])
    change(doc)
    (tmp_path / "annotations.json").write_text(json.dumps(doc))
    rc = cli_main(["import-coco", str(tmp_path / "annotations.json"), "--images", str(tmp_path / "photos"),
                   "--out", str(tmp_path / "yolo"), "--map", *maps])
    assert rc == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "yolo").exists()  # nothing written before everything was checked


def test_mapping_errors():
    with pytest.raises(ValueError, match="expected coco_name=our_name"):
        parse_mapping(["bread"])
    with pytest.raises(DatasetError):
        import_coco("/nonexistent.json", "/", "/tmp/never", OBJECT_CLASSES)


def _import(tmp_path, doc, maps=("Bread=bread", "person=")):
    (tmp_path / "annotations.json").write_text(json.dumps(doc))
    return cli_main(["import-coco", str(tmp_path / "annotations.json"), "--images", str(tmp_path / "photos"),
                     "--out", str(tmp_path / "yolo"), "--map", *maps])


def test_crowd_regions_are_skipped_and_counted_not_boxes(tmp_path, capsys):
    """Issue 20 item 11: CVAT exports `iscrowd: 1` regions (many objects under one outline); they were
    imported as one object's box."""
    write_images(tmp_path / "photos")
    doc = cvat_coco()
    doc["annotations"][0]["iscrowd"] = 1       # bread on frame_000
    doc["annotations"][3]["iscrowd"] = 1       # person on frame_001: no --map needed for a crowd only
    assert _import(tmp_path, doc, maps=("Bread=bread",)) == 0
    out = capsys.readouterr().out
    assert "skipped (iscrowd, a region of many objects, not a box): 1 Bread regions" in out
    labels = (tmp_path / "yolo" / "labels" / "train" / "frame_000.txt").read_text().splitlines()
    assert len(labels) == 1 and labels[0].startswith(f"{OBJECT_CLASSES.index('soda_can')} ")
    report = import_coco(tmp_path / "annotations.json", tmp_path / "photos", tmp_path / "yolo2",
                         OBJECT_CLASSES, parse_mapping(["Bread=bread"]))
    assert report.boxes == 2 and report.crowd == {"Bread": 1, "person": 1}


@pytest.mark.parametrize("where, change, message", [
    ("image", lambda d: d["images"][0].update(id=[1]), "annotations.json: image #0: id must be an integer"),
    ("annotation", lambda d: d["annotations"][1].update(image_id={"a": 1}),
     "annotations.json: annotation 2: image_id must be an integer or a string, got dict"),
    ("annotation", lambda d: d["annotations"][1].update(id=[2], category_id=[1]),
     "annotations.json: annotation #1: category_id must be an integer or a string, got list"),
    ("category", lambda d: d["categories"][2].update(id={"x": 3}),
     "annotations.json: category #2: id must be"),
])
def test_an_unhashable_id_is_a_clean_error(tmp_path, capsys, where, change, message):
    """Issue 20 item 11: an id that is a list or a mapping raised a TypeError."""
    write_images(tmp_path / "photos")
    doc = cvat_coco()
    change(doc)
    assert _import(tmp_path, doc) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "yolo").exists()


@pytest.mark.parametrize("name, message", [
    ("../outside/x.png", "the file name climbs out of"),
    ("images/../../outside/x.png", "the file name climbs out of"),
    ("/ABS/outside/x.png", "not found in"),       # looked up inside --images, never at that path
    ("linked.png", "is a link to a file outside"),
])
def test_image_paths_never_leave_the_images_folder(tmp_path, capsys, name, message):
    """Issue 20 item 11: `../outside/x.png` was copied from outside --images."""
    write_images(tmp_path / "photos")
    outside = tmp_path / "outside"
    outside.mkdir()
    cv2.imwrite(str(outside / "x.png"), np.full((H, W, 3), 7, np.uint8))
    (tmp_path / "photos" / "linked.png").symlink_to(outside / "x.png")
    doc = cvat_coco()
    doc["images"][2]["file_name"] = name.replace("/ABS", str(tmp_path))
    assert _import(tmp_path, doc) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "yolo").exists()
