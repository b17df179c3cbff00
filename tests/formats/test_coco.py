import datetime
import json

import numpy as np
import pytest

from spm_data.formats.coco import (load_scene_gt_coco, mask_bbox, mask_to_rle, rle_to_mask, save_scene_gt_coco,
                           scene_coco)
from spm_data.errors import SpmError

# Rows of a 3x4 mask; read column by column it is 0 1 0 | 1 1 0 | 1 0 0 | 0 0 1.
MASK_3X4 = np.array([[0, 1, 1, 0],
                     [1, 1, 0, 0],
                     [0, 0, 0, 1]], dtype=bool)
CREATED = datetime.datetime(2026, 3, 4, 5, 6, 7, tzinfo=datetime.timezone.utc)


def test_rle_of_a_3x4_mask_by_hand():
    # Runs over 0 1 0 1 1 0 1 0 0 0 0 1: background first.
    assert mask_to_rle(MASK_3X4) == {"counts": [1, 1, 1, 2, 1, 1, 4, 1], "size": [3, 4]}
    # uint8 0/255 (a BOP mask PNG) encodes the same.
    assert mask_to_rle(MASK_3X4.astype(np.uint8) * 255) == {"counts": [1, 1, 1, 2, 1, 1, 4, 1], "size": [3, 4]}


def test_rle_starts_with_an_empty_run_when_the_first_pixel_is_set():
    mask = np.zeros((3, 4), bool)
    mask[0, 0] = mask[2, 3] = True
    assert mask_to_rle(mask) == {"counts": [0, 1, 10, 1], "size": [3, 4]}
    assert mask_to_rle(np.zeros((3, 4), bool))["counts"] == [12]
    assert mask_to_rle(np.ones((3, 4), bool))["counts"] == [0, 12]


def _cases():
    rng = np.random.default_rng(7)
    cases = {f"random-{p}": rng.random((17, 23)) < p for p in (0.05, 0.5, 0.95)}
    cases["zeros"] = np.zeros((5, 6), bool)
    cases["ones"] = np.ones((5, 6), bool)
    for name, pixels in {"first": [(0, 0)], "last": [(4, 5)], "first-and-last": [(0, 0), (4, 5)]}.items():
        mask = np.zeros((5, 6), bool)
        for r, c in pixels:
            mask[r, c] = True
        cases[name] = mask
    cases["row"] = rng.random((1, 40)) < 0.5
    cases["column"] = rng.random((40, 1)) < 0.5
    return cases


@pytest.mark.parametrize("name", list(_cases()))
def test_rle_round_trip(name):
    mask = _cases()[name]
    rle = mask_to_rle(mask)
    assert rle["size"] == list(mask.shape) and sum(rle["counts"]) == mask.size
    assert all(c > 0 for c in rle["counts"][1:])  # only the first run may be empty
    back = rle_to_mask(rle)
    assert back.dtype == bool
    np.testing.assert_array_equal(back, mask)


def test_rle_to_mask_refuses_counts_that_do_not_fill_the_size():
    with pytest.raises(SpmError, match="sum to 11, size 3x4 needs 12"):
        rle_to_mask({"counts": [1, 1, 9], "size": [3, 4]})
    with pytest.raises(SpmError, match="non-negative"):
        rle_to_mask({"counts": [13, -1], "size": [3, 4]})


def test_mask_bbox():
    assert mask_bbox(MASK_3X4) == [0, 0, 4, 3]
    one = np.zeros((5, 6), np.uint8)
    one[1, 2] = 255
    assert mask_bbox(one) == [2, 1, 1, 1]
    block = np.zeros((5, 6), bool)
    block[2:4, 1:5] = True
    assert mask_bbox(block) == [1, 2, 4, 2]
    assert mask_bbox(np.zeros((5, 6), bool)) == [0, 0, 0, 0]
    assert all(type(v) is int for v in mask_bbox(block))


def _frames():
    small = np.zeros((3, 4), bool)
    small[2, 3] = True
    full = np.zeros((3, 4), bool)
    full[1:3, 2:4] = True
    return [{"im_id": 5, "file_name": "rgb/000005.jpg", "width": 4, "height": 3, "objects": [
                {"obj_id": 2, "mask_visib": MASK_3X4.astype(np.uint8) * 255, "visib_fract": 0.8, "mask": MASK_3X4},
                {"obj_id": 7, "mask_visib": small, "visib_fract": 0.05, "mask": full},
                {"obj_id": 7, "mask_visib": np.zeros((3, 4), bool), "visib_fract": 0.0, "mask": full}]},
            {"im_id": 9, "file_name": "rgb/000009.jpg", "width": 4, "height": 3, "objects": [
                {"obj_id": 2, "mask_visib": ~MASK_3X4, "visib_fract": 0.1, "mask": np.ones((3, 4), bool)}]}]


def test_scene_coco_layout_and_masks_decode_back():
    payload = scene_coco(_frames(), dataset="lm", split="train", created=CREATED)
    assert list(payload) == ["info", "licenses", "categories", "images", "annotations"]
    assert payload["info"] == {"description": "lm_train", "url": "https://github.com/thodan/bop_toolkit",
                               "version": "0.1.0", "year": 2026, "contributor": "",
                               "date_created": "2026-03-04 05:06:07+00:00"}
    assert payload["licenses"] == []
    assert payload["categories"] == [{"id": 2, "name": "2", "supercategory": "lm"},
                                     {"id": 7, "name": "7", "supercategory": "lm"}]
    assert payload["images"][0] == {"id": 5, "file_name": "rgb/000005.jpg", "width": 4, "height": 3,
                                    "date_captured": "2026-03-04 05:06:07+00:00", "license": 1,
                                    "coco_url": "", "flickr_url": ""}
    anns = payload["annotations"]
    # The empty visible mask is left out, and ids stay consecutive over the scene.
    assert [(a["id"], a["image_id"], a["category_id"]) for a in anns] == [(1, 5, 2), (2, 5, 7), (3, 9, 2)]
    assert [a["area"] for a in anns] == [5, 1, 7]
    assert [a["bbox"] for a in anns] == [[0, 0, 4, 3], [3, 2, 1, 1], [0, 0, 4, 3]]
    # visib_fract < 0.1 is ignored; exactly 0.1 is not.
    assert [a["ignore"] for a in anns] == [False, True, False]
    assert all(a["iscrowd"] == 0 and a["width"] == 4 and a["height"] == 3 for a in anns)
    assert anns[0]["segmentation"] == {"counts": [1, 1, 1, 2, 1, 1, 4, 1], "size": [3, 4]}
    expected = [MASK_3X4, _frames()[0]["objects"][1]["mask_visib"], ~MASK_3X4]
    for ann, mask in zip(anns, expected):
        np.testing.assert_array_equal(rle_to_mask(ann["segmentation"]), mask)


def test_scene_coco_amodal_boxes_and_listed_categories():
    payload = scene_coco(_frames(), dataset="lm", bbox_type="amodal", obj_ids=[1, 2, 7], created=CREATED)
    assert [a["bbox"] for a in payload["annotations"]] == [[0, 0, 4, 3], [2, 1, 2, 2], [0, 0, 4, 3]]
    assert [c["id"] for c in payload["categories"]] == [1, 2, 7]
    # The segmentation stays the visible mask.
    assert payload["annotations"][1]["segmentation"] == {"counts": [11, 1], "size": [3, 4]}


def test_scene_coco_refuses_a_mask_of_another_size():
    frames = _frames()
    frames[1]["objects"][0]["mask_visib"] = np.ones((4, 3), bool)
    with pytest.raises(SpmError, match=r"image 9 \(rgb/000009.jpg\): object 2's mask has shape \(4, 3\)"):
        scene_coco(frames, dataset="lm")


def test_save_and_load_round_trip(tmp_path):
    payload = scene_coco(_frames(), dataset="lm", created=CREATED)
    path = tmp_path / "scene_gt_coco.json"
    save_scene_gt_coco(path, payload)
    assert load_scene_gt_coco(path) == payload
    # One top-level key a line (bop_toolkit's layout), and no temporary file left.
    lines = path.read_text().splitlines()
    assert lines[0] == "{" and lines[-1] == "}" and len(lines) == 7
    assert [p.name for p in tmp_path.iterdir()] == ["scene_gt_coco.json"]


def _broken(payload):
    ann = payload["annotations"][0]["segmentation"]
    return {
        "missing key": lambda: payload.pop("images"),
        "counts sum": lambda: ann["counts"].append(1),
        "size": lambda: ann.update(size=[4, 3], counts=[12]),
        "compressed": lambda: ann.update(counts="52203"),
        "image id": lambda: payload["annotations"][0].update(image_id=99),
    }


@pytest.mark.parametrize("case,message", [
    ("missing key", "missing or mistyped top-level key"),
    ("counts sum", "annotation 1: RLE counts sum to 13, size 3x4 needs 12"),
    ("size", r"annotation 1: RLE size \[4, 3\] is not image 5's \[height, width\] \[3, 4\]"),
    ("compressed", "annotation 1: RLE counts are compressed"),
    ("image id", "annotation 1: image_id not among the images"),
])
def test_load_refuses_a_broken_file(tmp_path, case, message):
    payload = scene_coco(_frames(), dataset="lm", created=CREATED)
    _broken(payload)[case]()
    path = tmp_path / "scene_gt_coco.json"
    path.write_text(json.dumps(payload))
    with pytest.raises(SpmError, match=message) as info:
        load_scene_gt_coco(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_load_refuses_missing_and_unreadable_files(tmp_path):
    with pytest.raises(SpmError, match="COCO ground truth missing"):
        load_scene_gt_coco(tmp_path / "none.json")
    path = tmp_path / "scene_gt_coco.json"
    path.write_text('{"info": {}, "licenses": [')
    with pytest.raises(SpmError, match="unreadable JSON") as info:
        load_scene_gt_coco(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
