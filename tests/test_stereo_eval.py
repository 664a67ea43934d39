"""Matchers, dataset readers, metrics and ``avoidd eval`` (synthetic and real data)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from avoidd.cli import main
from avoidd.config import CensusConfig, SadConfig, SgbmConfig
from avoidd.evaluation.datasets import Calib, find_scenes, read_pfm
from avoidd.evaluation.metrics import details, score
from avoidd.evaluation.run import evaluate
from avoidd.pipeline import HeadPipeline
from avoidd.sources.scene import Box, Pole, Scene
from avoidd.types import RectifiedRig, StereoFrame
from avoidd.vision.matchers import create_matcher
from avoidd.vision.matchers.border import crop_padded
from avoidd.vision.matchers.census import PATTERNS, census_transform, texture_mask
from tests.helpers import noisy_grey_pair

RIG = RectifiedRig(480, 360, 300.0, 300.0, 239.5, 179.5, 0.12, 0.0)
NUM_DISPARITIES = 48


@pytest.fixture(scope="module")
def textured_pair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rendered scene with exact disparity (NaN for sky)."""
    scene = Scene(
        camera_height_m=1.4,
        camera_pitch_deg=0.0,
        obstacles=(
            Box(2.2, -1.0, 0.8, 1.0, 2.5),
            Pole(3.0, 0.6, 0.3, 3.0),
            Box(5.0, 1.2, 1.5, 1.0, 3),
        ),
        backdrop_m=30.0,
        seed=4,
    )
    left, right, ground_truth = noisy_grey_pair(scene, RIG, 2, 1.0)
    depth = ground_truth.depth_m
    truth = np.where(np.isfinite(depth), RIG.fx * RIG.baseline_m / depth, np.nan).astype(np.float32)
    return left, right, truth


@pytest.mark.parametrize(
    ("config", "min_density"),
    [
        (SgbmConfig(num_disparities=NUM_DISPARITIES), 92.0),
        (SgbmConfig(num_disparities=NUM_DISPARITIES, pad_left=False), 82.0),
        (SadConfig(kind="sad", num_disparities=NUM_DISPARITIES), 70.0),
        (SadConfig(kind="sad", num_disparities=NUM_DISPARITIES, pad_left=True), 78.0),
        (CensusConfig(kind="census", num_disparities=NUM_DISPARITIES), 90.0),
        (CensusConfig(kind="census", num_disparities=NUM_DISPARITIES, pattern="full5x5"), 90.0),
    ],
)
def test_matchers_recover_known_disparity(
    textured_pair: tuple[np.ndarray, np.ndarray, np.ndarray],
    config: SgbmConfig | SadConfig | CensusConfig,
    min_density: float,
) -> None:
    left, right, truth = textured_pair
    disparity = create_matcher(config).compute(left, right)
    assert disparity.dtype == np.float32 and disparity.shape == truth.shape
    scores = score(disparity, truth, None, 0.0)
    wrong = scores.bad2 - (100.0 - scores.density)  # estimates off by more than 2 px
    assert wrong <= 3.0, scores
    assert scores.density >= min_density, scores
    assert scores.avgerr <= 0.4, scores
    valid = np.isfinite(disparity)
    assert np.all(disparity[valid] >= 0) and np.all(disparity[valid] < NUM_DISPARITIES)


def test_padding_matches_the_border_band_but_never_into_the_padding(
    textured_pair: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> None:
    left, right, truth = textured_pair
    padded = create_matcher(SgbmConfig(num_disparities=NUM_DISPARITIES)).compute(left, right)
    plain = create_matcher(SgbmConfig(num_disparities=NUM_DISPARITIES, pad_left=False)).compute(
        left, right
    )
    band = (slice(None), slice(0, NUM_DISPARITIES))
    assert np.isnan(plain[band]).all()  # OpenCV leaves the band unmatched
    assert np.isfinite(padded[band]).mean() > 0.5  # padding matches most of it
    x = np.arange(truth.shape[1])[None, :]
    assert not np.any(padded > x)  # no match points into the padding
    error = np.abs(padded[band] - truth[band])
    assert np.nanmedian(error) < 0.5


def test_census_bits_say_which_neighbours_are_darker() -> None:
    image = np.full((7, 7), 100, dtype=np.uint8)
    image[1, 1] = 50  # (-2, -2) of the centre (3, 3): darker -> bit 0
    image[3, 5] = 200  # (0, +2): brighter -> bit 4 stays 0
    image[5, 5] = 99  # (+2, +2): darker -> bit 7
    (plane,) = census_transform(image, PATTERNS["sparse5x5"])
    assert plane[3, 3] == 0b1000_0001
    planes = census_transform(image, PATTERNS["full5x5"])
    assert len(planes) == 3 and all(p.dtype == np.uint8 for p in planes)


def test_texture_mask_rejects_flat_regions() -> None:
    rng = np.random.default_rng(1)
    image = np.full((40, 40), 128, dtype=np.uint8)
    image[:, 20:] = rng.integers(0, 255, (40, 20), dtype=np.uint8)
    mask = texture_mask(image, 7, 1.0)
    assert not mask[:, :15].any() and mask[:, 25:].all()


def test_census_beats_sad_and_handles_the_border_band_without_padding(
    textured_pair: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> None:
    left, right, truth = textured_pair
    census = create_matcher(CensusConfig(kind="census", num_disparities=NUM_DISPARITIES))
    disparity = census.compute(left, right)
    x = np.arange(truth.shape[1])[None, :]
    assert not np.any(disparity > x)  # the band searches only matches inside the image
    assert np.isfinite(disparity[:, :NUM_DISPARITIES]).mean() > 0.5


def test_crop_padded_drops_matches_in_the_padding() -> None:
    disparity = np.array([[9.0, 9.0, 1.0, 2.5, 2.0, 0.0]], dtype=np.float32)
    cropped = crop_padded(disparity, 2)
    assert cropped.shape == (1, 4)
    assert np.isnan(cropped[0, 0])  # 1.0 at x=0: its match would be at x=-1
    assert np.isnan(cropped[0, 1])  # 2.5 at x=1
    assert cropped[0, 2] == 2.0 and cropped[0, 3] == 0.0  # matches inside the image stay


def test_scores_by_hand() -> None:
    truth = np.array([[10.0, 10.0, 10.0, 10.0, np.nan]], dtype=np.float32)
    estimate = np.array([[10.5, 11.5, 13.0, np.nan, 5.0]], dtype=np.float32)
    calib = Calib(focal_px=100.0, baseline_m=0.1, doffs_px=0.0)
    s = score(estimate, truth, calib, 12.0)
    # 4 pixels with truth; errors 0.5, 1.5, 3.0 and one missing.
    assert s.bad1 == pytest.approx(75.0)
    assert s.bad2 == pytest.approx(50.0)
    assert s.bad4 == pytest.approx(25.0)
    assert s.density == pytest.approx(75.0)
    assert s.avgerr == pytest.approx((0.5 + 1.5 + 3.0) / 3)
    # Depth 1.0 m true; 0.952 (4.8% off), 0.870 (13%), 0.769 (23%), missing: 3 of 4 bad.
    assert s.depth_bad10 == pytest.approx(75.0)
    assert s.ms == 12.0


def test_details_by_hand() -> None:
    truth = np.array([[10.0, 10.0, 10.0, 10.0, np.nan, 4.0]], dtype=np.float32)
    estimate = np.array([[7.0, 10.5, 9.0625, 10.0, 5.0, 1.5]], dtype=np.float32)
    d = details(estimate, truth, 2)
    # Whole pixels: 7.0, 10.0, 5.0 of six estimates (9.0625 is a 1/16 step off).
    assert d.whole_px == pytest.approx(50.0)
    # Within 1 px of the truth: 0.5, 0.9375 and 0.0.
    assert d.fine_err == pytest.approx((0.5 + 0.9375 + 0.0) / 3)
    # Band (columns 0-1): 7.0 reads 3 px too far, 10.5 does not. Right of it: 9.0625, 10.0
    # and 1.5 (2.5 px too far) have truth.
    assert d.band_too_far == pytest.approx(50.0)
    assert d.rest_too_far == pytest.approx(100.0 / 3)


def _write_pfm(path: Path, image: np.ndarray) -> None:
    height, width = image.shape
    header = f"Pf\n{width} {height}\n-1.0\n".encode()
    path.write_bytes(header + image[::-1].astype("<f4").tobytes())


def test_readers_of_every_layout(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (20, 40, 3), dtype=np.uint8)
    truth = np.full((20, 40), 12.5, dtype=np.float32)
    truth[0, 0] = np.inf
    truth[19, 39] = 30.0

    m14 = tmp_path / "m14" / "Toy"
    m14.mkdir(parents=True)
    cv2.imwrite(str(m14 / "im0.png"), image)
    cv2.imwrite(str(m14 / "im1.png"), image)
    _write_pfm(m14 / "disp0GT.pfm", truth)
    (m14 / "calib.txt").write_text(
        "cam0=[500.0 0 20; 0 500.0 10; 0 0 1]\ncam1=[500.0 0 25; 0 500.0 10; 0 0 1]\n"
        "doffs=5.0\nbaseline=120.0\nwidth=40\nheight=20\nndisp=40\n"
    )
    tsukuba = tmp_path / "m01" / "tsukuba"
    tsukuba.mkdir(parents=True)
    cv2.imwrite(str(tsukuba / "imL.png"), image)
    cv2.imwrite(str(tsukuba / "imR.png"), image)
    cv2.imwrite(str(tsukuba / "truedisp.pgm"), np.full((20, 40), 80, np.uint8))  # 5 px
    venus = tmp_path / "m01" / "venus"
    venus.mkdir(parents=True)
    cv2.imwrite(str(venus / "im2.ppm"), image)
    cv2.imwrite(str(venus / "im6.ppm"), image)
    gt8 = np.full((20, 40), 80, np.uint8)
    gt8[5, 5] = 0
    cv2.imwrite(str(venus / "disp2.pgm"), gt8)  # 10 px, one unknown
    cones = tmp_path / "m03" / "cones"
    cones.mkdir(parents=True)
    cv2.imwrite(str(cones / "im2.png"), image)
    cv2.imwrite(str(cones / "im6.png"), image)
    cv2.imwrite(str(cones / "disp2.png"), np.full((20, 40), 80, np.uint8))  # 20 px
    kitti = tmp_path / "kitti"
    for sub in ("image_2", "image_3", "disp_occ_0"):
        (kitti / sub).mkdir(parents=True)
    cv2.imwrite(str(kitti / "image_2" / "000000_10.png"), image)
    cv2.imwrite(str(kitti / "image_3" / "000000_10.png"), image)
    cv2.imwrite(str(kitti / "disp_occ_0" / "000000_10.png"), np.full((20, 40), 256 * 7, np.uint16))

    pfm = read_pfm(m14 / "disp0GT.pfm")
    assert np.isnan(pfm[0, 0]) and pfm[19, 39] == 30.0 and pfm[5, 5] == 12.5

    scenes = {s.name: s for s in find_scenes(tmp_path)}
    assert set(scenes) == {"m14/Toy", "m01/tsukuba", "m01/venus", "m03/cones", "kitti/000000_10"}
    toy = scenes["m14/Toy"]
    assert toy.calib == Calib(500.0, 0.12, 5.0) and toy.num_disparities == 48
    assert np.nanmax(scenes["m01/tsukuba"].truth_px) == 5.0
    # The search range comes from the encoding (value / 16 holds at most 15.9 px; value / 8,
    # 31.9; value / 4, 63.75), never from the truth's own maximum (5, 10 and 20 px here).
    assert scenes["m01/tsukuba"].num_disparities == 16
    assert scenes["m01/venus"].num_disparities == 32
    assert scenes["m03/cones"].num_disparities == 64
    venus_truth = scenes["m01/venus"].truth_px
    assert np.isnan(venus_truth[5, 5]) and venus_truth[0, 0] == 10.0
    assert scenes["m03/cones"].truth_px[0, 0] == 20.0
    assert scenes["kitti/000000_10"].truth_px[3, 3] == 7.0
    assert scenes["kitti/000000_10"].num_disparities == 192
    assert all(s.num_disparities % 16 == 0 for s in scenes.values())


def test_eval_command_writes_the_json_the_issue_specifies(
    tmp_path: Path, textured_pair: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> None:
    left, right, truth = textured_pair
    scene = tmp_path / "synthetic" / "street"
    scene.mkdir(parents=True)
    cv2.imwrite(str(scene / "im0.png"), cv2.cvtColor(left, cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(scene / "im1.png"), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR))
    _write_pfm(scene / "disp0GT.pfm", np.where(np.isnan(truth), np.inf, truth))
    (scene / "calib.txt").write_text(
        f"cam0=[{RIG.fx} 0 {RIG.cx}; 0 {RIG.fy} {RIG.cy}; 0 0 1]\ndoffs=0\n"
        f"baseline={RIG.baseline_m * 1000}\nndisp={NUM_DISPARITIES}\n"
    )
    out = tmp_path / "eval.json"
    assert main(["eval", str(tmp_path), "--matcher", "sgbm", "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["matcher"] == "sgbm"
    assert [s["scene"] for s in document["scenes"]] == ["synthetic/street"]
    keys = {"bad1", "bad2", "bad4", "density", "avgerr", "ms"}
    assert keys <= set(document["scenes"][0]) and keys <= set(document["mean"])
    assert 0.0 <= document["mean"]["bad2"] <= 10.0
    assert document["mean"]["depth_bad10"] is not None
    assert main(["eval", str(tmp_path), "--matcher", "nope"]) == 2


# Figures quoted below are the project's own measurements on this data (the data's README
# publishes none), printed as the MEAN row of:
#   avoidd eval $AVOIDD_DATA/middlebury2014_Q --matcher opencv-sgbm --matcher sgbm
#       --matcher sad --matcher census --matcher segment
#   avoidd eval $AVOIDD_DATA/middlebury2003 --matcher sgbm --matcher sgbm-gated (and 2001)
#   avoidd eval $AVOIDD_DATA/middlebury2014_Q --max-scenes 6 --matcher sgbm-raw
#       --matcher sgbm --matcher sgbm-refined
# A "regression bound" sits a little outside what was measured: it fails when a change makes
# a matcher clearly worse, and says nothing more than that.


def test_eval_on_middlebury_2014_beats_the_opencv_baseline(data_dir: Path) -> None:
    runs = {
        r.matcher: r.mean
        for r in evaluate(
            data_dir / "middlebury2014_Q", ["opencv-sgbm", "sgbm", "sad", "census", "segment"]
        )
    }
    baseline, ours, sad, census, segment = (
        runs[n] for n in ("opencv-sgbm", "sgbm", "sad", "census", "segment")
    )
    # Regression bound on the baseline itself (measured 33.5% bad-2 at 75.6% density): bare
    # OpenCV SGBM scored as before, so the comparisons below compare against the same thing.
    assert 31.0 <= baseline.bad2 <= 36.0 and 73.0 <= baseline.density <= 78.0
    # Better bad-2 at no lower density. The target was 20% better (25.8% at 86.0%), but part
    # of that lead was left-border-band readings too far (issue 53): the band now keeps only
    # readings the right view confirms, 27.2% at 83.6%, 19% better (docs/perception.md).
    assert ours.bad2 <= 0.83 * baseline.bad2, (ours, baseline)
    assert ours.density >= baseline.density
    assert ours.bad2 <= 27.6 and ours.density >= 83.0  # regression bound
    assert sad.bad2 <= 53.0 and sad.density >= 50.0  # regression bound (measured 49.5 at 54.1)
    assert census.bad2 < sad.bad2 - 10.0  # census is the more accurate (measured 36.4 vs 49.5)
    assert census.bad2 <= 38.5 and census.density >= 67.0  # regression bound (36.4 at 69.2)
    # The paper's hybrid, between census and SAD: regression bound (measured 44.9 at 62.1).
    assert segment.bad2 <= 48.0 and segment.density >= 59.0
    # Regression bound on depth off by more than 10% (measured 20.5; 22.3 since the band keeps
    # only confirmed readings: unconfirmed ones now count as missing).
    assert ours.depth_bad10 is not None and ours.depth_bad10 <= 23.0
    assert math.isfinite(ours.avgerr)


def test_eval_on_middlebury_2001_and_2003(data_dir: Path) -> None:
    # Regression bounds on sgbm's bad-2 (measured 5.2 on 2001, 16.0 on 2003).
    for dataset, max_bad2 in (("middlebury2001", 6.5), ("middlebury2003", 17.5)):
        run, gated = evaluate(data_dir / dataset, ["sgbm", "sgbm-gated"])
        assert run.mean.bad2 <= max_bad2, (dataset, run.mean)
        assert len(run.scenes) == (7 if dataset == "middlebury2001" else 2)
        # The texture gate costs some density on real images, never most of it (measured
        # 97.1 -> 85.9 on 2001 and 89.4 -> 80.8 on 2003; an earlier gate, since replaced, that
        # estimated noise over the whole image left 57 and 59).
        assert gated.mean.density >= run.mean.density - 15.0, (dataset, gated.mean)


def test_eval_where_both_cameras_see_on_middlebury_2014(data_dir: Path) -> None:
    # The baseline for improving the matcher right of the border band (docs/stereo.md,
    # "Where both cameras see"); measured bad-2 / density: opencv-sgbm 23.2 / 87.3, sgbm
    # 21.4 / 90.7 over columns >= ndisp, against 33.5 / 75.6 and 25.8 / 86.0 over all.
    runs = {
        r.matcher: r
        for r in evaluate(data_dir / "middlebury2014_Q", ["opencv-sgbm", "sgbm"], region="overlap")
    }
    baseline, ours = runs["opencv-sgbm"].mean, runs["sgbm"].mean
    assert 21.5 <= baseline.bad2 <= 25.0 and 85.5 <= baseline.density <= 89.0  # regression bound
    assert ours.bad2 <= 23.0 and ours.density >= 89.0  # regression bound
    # Leaving out the band, where bare SGBM has nothing, raises the baseline's density most.
    assert ours.density - baseline.density < 86.0 - 75.6
    assert runs["sgbm"].num_disparities[0] == 80  # Adirondack's calib.txt ndisp, not its truth


def test_default_post_processing_does_no_harm_on_real_images(data_dir: Path) -> None:
    # Post-processing may only keep or improve what the matcher measured. Measured on the
    # first six Middlebury 2014 Q scenes (bad-1 / avg error): raw 29.0 / 2.61, default
    # 28.9 / 2.60, with the refinement step 30.3 / 2.73 (all 15 scenes: 29.9 / 2.36,
    # 29.7 / 2.35, 30.8 / 2.44); an earlier median, since replaced, that counted holes as
    # zero gave 2.70.
    runs = {
        r.matcher: r
        for r in evaluate(
            data_dir / "middlebury2014_Q", ["sgbm-raw", "sgbm", "sgbm-refined"], max_scenes=6
        )
    }
    raw, default, refined = (runs[n].mean for n in ("sgbm-raw", "sgbm", "sgbm-refined"))
    assert default.density == raw.density  # the median never adds or drops a pixel
    assert default.bad1 <= raw.bad1 and default.avgerr <= raw.avgerr, (default, raw)
    # The reason refinement is off by default: it raises the sub-pixel error here.
    assert refined.avgerr > default.avgerr and refined.bad1 > default.bad1, (refined, default)


def test_bench_times_a_recorded_sequence_with_its_own_calibration(
    data_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from avoidd.bench.vision import euroc_frames, run_bench

    sequence = euroc_frames(data_dir / "euroc" / "V1_01_easy_micro", 2)
    assert len(sequence.pairs) == 2 and sequence.pairs[0].left.ndim == 2
    assert sequence.calibration.maps is not None  # raw images: rectify does real work
    timed: list[int] = []
    real_process = HeadPipeline.process

    def counting(self: HeadPipeline, frame: StereoFrame, *args: Any, **kwargs: Any) -> Any:
        timed.append(id(frame))
        return real_process(self, frame, *args, **kwargs)

    monkeypatch.setattr(HeadPipeline, "process", counting)
    records = run_bench(["sgbm"], (), (64,), frames=2, recorded=[sequence])
    assert [r["source"] for r in records] == ["V1_01_easy_micro"] * 2
    # Per thread setting: a warm-up on the first pair, then exactly the pairs of the sequence.
    pairs = [id(p) for p in sequence.pairs]
    assert timed == [pairs[0], *pairs] * 2
    for record in records:
        assert (record["width"], record["height"]) == (752, 480)
        assert record["stages_ms"]["rectify"] > 0.0 and record["stages_ms"]["obstacles"] > 0.0


def test_bench_refuses_a_folder_that_is_no_sequence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "--quick", "--frames", "1", "--euroc", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "mav0" in err
