"""``avoidd eval``: dataset layouts, the search range, the scored region, threads, errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from avoidd.cli import main
from avoidd.evaluation.datasets import (
    LAYOUTS,
    find_scenes,
    load_scene,
    middlebury_2005_factor,
    round_up_16,
)
from avoidd.evaluation.metrics import region_mask, score
from avoidd.evaluation.run import evaluate


def _image(path: Path, shape: tuple[int, int] = (20, 40)) -> None:
    rng = np.random.default_rng(0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), rng.integers(0, 255, (*shape, 3), dtype=np.uint8))


def _pair(folder: Path, left: str, right: str, shape: tuple[int, int] = (20, 40)) -> None:
    _image(folder / left, shape)
    _image(folder / right, shape)


def _coded(shape: tuple[int, int], value: int, dtype: type = np.uint8) -> np.ndarray:
    truth = np.full(shape, value, dtype=dtype)
    truth[1, 1] = 0  # one unknown pixel
    return truth


@pytest.mark.parametrize(
    ("rows", "factor", "default_range"),
    [(370, 3, 96), (555, 2, 128), (1110, 1, 256)],  # third, half and full size
)
def test_middlebury_2005_2006_disparity_is_divided_by_the_size_factor(
    tmp_path: Path, rows: int, factor: int, default_range: int
) -> None:
    scene_dir = tmp_path / "m06" / "Aloe"
    _pair(scene_dir, "view1.png", "view5.png", (rows, 24))
    cv2.imwrite(str(scene_dir / "disp1.png"), _coded((rows, 24), 60))
    (scene,) = find_scenes(tmp_path)
    assert scene.name == "m06/Aloe" and scene.layout == "Middlebury 2005/2006"
    assert middlebury_2005_factor(rows) == factor
    assert scene.truth_px[5, 5] == pytest.approx(60.0 / factor)
    assert np.isnan(scene.truth_px[1, 1])
    # The range the 8-bit encoding holds (255 / factor), rounded up to 16.
    assert scene.num_disparities == default_range


def test_middlebury_2005_dmin_is_added_to_known_disparities(tmp_path: Path) -> None:
    _pair(tmp_path, "view1.png", "view5.png", (1110, 16))
    cv2.imwrite(str(tmp_path / "disp1.png"), _coded((1110, 16), 100))
    (tmp_path / "dmin.txt").write_text("230\n")
    scene = load_scene(tmp_path)
    assert scene is not None
    assert scene.truth_px[5, 5] == pytest.approx(330.0)
    assert np.isnan(scene.truth_px[1, 1])  # 0 stays unknown, offset or not
    assert scene.num_disparities == round_up_16(255 + 230) == 496


def test_middlebury_2003_with_im_l_and_im_r_names(tmp_path: Path) -> None:
    _pair(tmp_path / "cones", "imL.png", "imR.png")
    cv2.imwrite(str(tmp_path / "cones" / "disp2.png"), _coded((20, 40), 80))
    (scene,) = find_scenes(tmp_path)
    assert scene.layout == "Middlebury 2003"
    assert scene.truth_px[5, 5] == 20.0 and np.isnan(scene.truth_px[1, 1])
    assert scene.num_disparities == 64


@pytest.mark.parametrize(
    ("left", "right", "truth_dirs", "used"),
    [
        ("image_2", "image_3", ("disp_occ_0", "disp_noc_0"), 7.0),  # KITTI 2015
        ("image_0", "image_1", ("disp_occ", "disp_noc"), 7.0),  # KITTI 2012
        ("image_2", "image_3", ("disp_occ_0",), 9.0),  # only all-pixel truth
    ],
)
def test_kitti_prefers_non_occluded_truth(
    tmp_path: Path, left: str, right: str, truth_dirs: tuple[str, ...], used: float
) -> None:
    kitti = tmp_path / "kitti"
    _image(kitti / left / "000000_10.png")
    _image(kitti / right / "000000_10.png")
    for sub in truth_dirs:
        (kitti / sub).mkdir()
        value = 7 if "noc" in sub else 9
        cv2.imwrite(str(kitti / sub / "000000_10.png"), _coded((20, 40), 256 * value, np.uint16))
    (scene,) = find_scenes(kitti)
    assert scene.name == "kitti/000000_10" and scene.layout == "KITTI 2012/2015"
    assert scene.truth_px[5, 5] == used and np.isnan(scene.truth_px[1, 1])
    assert scene.num_disparities == 192


def test_num_disparities_option_sets_every_scene_rounded_up(tmp_path: Path) -> None:
    _pair(tmp_path / "a", "im2.png", "im6.png")
    cv2.imwrite(str(tmp_path / "a" / "disp2.pgm"), _coded((20, 40), 80))
    _pair(tmp_path / "b", "view1.png", "view5.png")
    cv2.imwrite(str(tmp_path / "b" / "disp1.png"), _coded((20, 40), 30))
    scenes = list(find_scenes(tmp_path, num_disparities=20))
    assert [s.num_disparities for s in scenes] == [32, 32]
    assert [s.num_disparities for s in find_scenes(tmp_path, num_disparities=16)] == [16, 16]


def test_region_overlap_scores_only_columns_right_of_the_band() -> None:
    mask = region_mask((2, 6, 3), 2, "overlap")
    assert mask.shape == (2, 6) and not mask[:, :2].any() and mask[:, 2:].all()
    assert region_mask((2, 6), 2, "all").all()
    truth = np.full((1, 6), 5.0, dtype=np.float32)
    estimate = np.array([[np.nan, np.nan, 5.0, 5.5, 9.0, np.nan]], dtype=np.float32)
    everything = score(estimate, truth, None, 0.0)
    overlap = score(estimate, truth, None, 0.0, region_mask(truth.shape, 2, "overlap"))
    # All: 6 pixels, 3 estimates, 1 off by 4 px. Overlap: 4 pixels, 3 estimates.
    assert everything.density == pytest.approx(50.0) and everything.bad2 == pytest.approx(
        100.0 * 4 / 6
    )
    assert overlap.density == pytest.approx(75.0) and overlap.bad2 == pytest.approx(50.0)
    with pytest.raises(ValueError, match="region"):
        region_mask((2, 6), 2, "middle")


def _textured_scene(root: Path, shift_px: int = 8) -> Path:
    """A Middlebury 2001 scene: random texture shifted by a constant disparity."""
    rng = np.random.default_rng(3)
    wide = cv2.GaussianBlur(rng.integers(0, 255, (96, 200), dtype=np.uint8), (3, 3), 0)
    left = wide[:, :160]
    right = wide[:, shift_px : shift_px + 160]  # right[x - d] == left[x]
    scene = root / "m01" / "plane"
    scene.mkdir(parents=True)
    cv2.imwrite(str(scene / "im2.png"), cv2.cvtColor(left, cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(scene / "im6.png"), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(scene / "disp2.pgm"), np.full((96, 160), shift_px * 8, np.uint8))
    return scene


def test_eval_region_overlap_leaves_out_the_band_bare_sgbm_cannot_fill(tmp_path: Path) -> None:
    _textured_scene(tmp_path)
    everything, overlap = (
        evaluate(tmp_path, ["opencv-sgbm"], region=region)[0] for region in ("all", "overlap")
    )
    assert everything.num_disparities == overlap.num_disparities == [32]
    # Bare SGBM leaves the first 32 of 160 columns empty: at most 80% density over all.
    assert everything.mean.density <= 81.0
    assert overlap.mean.density >= 95.0 and overlap.mean.bad2 <= 5.0
    assert overlap.region == "overlap" and everything.region == "all"


def test_eval_threads_are_set_for_the_run_and_restored(tmp_path: Path) -> None:
    _textured_scene(tmp_path)
    before = cv2.getNumThreads()
    out = tmp_path / "eval.json"
    options = ["--threads", "1", "--region", "overlap", "--num-disparities", "20"]
    code = main(["eval", str(tmp_path), "--matcher", "opencv-sgbm", *options, "--json", str(out)])
    assert code == 0
    assert cv2.getNumThreads() == before
    document = json.loads(out.read_text())
    assert document["threads"] == 1 and document["region"] == "overlap"
    assert document["scenes"][0]["num_disparities"] == 32


def test_eval_without_a_recognised_layout_names_each_layout_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "im0.png").write_bytes(b"")  # half a layout is no layout
    assert main(["eval", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "no stereo scene with ground truth" in err
    for name, files in LAYOUTS:
        assert f"{name}: {files}" in err
    assert "configuration invalid" not in err
    assert err.count("no stereo scene") == 1


def test_eval_rejects_a_search_range_that_is_not_positive(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", str(tmp_path), "--num-disparities", "0"])
    assert exit_info.value.code == 2
    assert "must be 1 or more" in capsys.readouterr().err
