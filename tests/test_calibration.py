from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from avoidd.vision.calibration import load_calibration
from avoidd.vision.rectify import rectify_pair

K1 = [[520.0, 0.0, 318.0], [0.0, 518.0, 243.0], [0.0, 0.0, 1.0]]
K2 = [[515.0, 0.0, 326.0], [0.0, 514.0, 236.0], [0.0, 0.0, 1.0]]
D1 = [-0.28, 0.07, 0.0002, 0.00002]
D2 = [-0.27, 0.075, -0.0001, -0.00004]
RVEC = np.array([0.004, -0.012, 0.006])  # the right camera is slightly rotated
T_M = [-0.11, 0.0008, -0.0012]


def write_stereo(tmp_path: Path) -> Path:
    rotation = cv2.Rodrigues(RVEC)[0].tolist()
    data = {
        "version": 1,
        "stereo": {
            "width": 640,
            "height": 480,
            "K1": K1,
            "D1": D1,
            "K2": K2,
            "D2": D2,
            "R": rotation,
            "T_m": T_M,
        },
    }
    path = tmp_path / "stereo.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_full_calibration_rectifies_rows_and_keeps_metric_depth(tmp_path: Path) -> None:
    calibration = load_calibration(write_stereo(tmp_path))
    rig = calibration.rig
    assert calibration.maps is not None
    assert rig.baseline_m == pytest.approx(float(np.linalg.norm(T_M)), rel=1e-3)
    assert rig.doffs_px == 0.0

    # Points seen by both raw cameras, projected with OpenCV (distortion included).
    rng = np.random.default_rng(3)
    z = rng.uniform(2.0, 12.0, 60)
    points = np.stack([rng.uniform(-0.4, 0.4, 60) * z, rng.uniform(-0.3, 0.3, 60) * z, z], 1)
    raw_left = cv2.projectPoints(points, np.zeros(3), np.zeros(3), np.array(K1), np.array(D1))[0]
    raw_right = cv2.projectPoints(points, RVEC, np.array(T_M), np.array(K2), np.array(D2))[0]

    # Our remap tables send a rectified pixel to a raw one; invert them by a few Newton steps.
    maps = [
        cv2.convertMaps(m[0], m[1], cv2.CV_32FC1)
        for m in (calibration.maps.left, calibration.maps.right)
    ]

    def sample(map_x: np.ndarray, map_y: np.ndarray, u: float, v: float) -> np.ndarray:
        patch = np.array([[[u, v]]], dtype=np.float32)
        x = cv2.remap(map_x, patch[..., 0], patch[..., 1], cv2.INTER_LINEAR)[0, 0]
        y = cv2.remap(map_y, patch[..., 0], patch[..., 1], cv2.INTER_LINEAR)[0, 0]
        return np.array([x, y])

    def to_rectified(index: int, raw: np.ndarray) -> np.ndarray:
        map_x, map_y = maps[index]
        uv = raw.astype(np.float64).copy()
        for _ in range(8):
            here = sample(map_x, map_y, *uv)
            jac = (
                np.column_stack(
                    [
                        sample(map_x, map_y, uv[0] + 0.5, uv[1]) - here,
                        sample(map_x, map_y, uv[0], uv[1] + 0.5) - here,
                    ]
                )
                / 0.5
            )
            uv = uv + np.linalg.solve(jac, raw - here)
        return uv

    row_errors, depth_errors = [], []
    for i in range(len(points)):
        left = to_rectified(0, raw_left[i, 0])
        right = to_rectified(1, raw_right[i, 0])
        inside = all(0 <= p[0] < rig.width and 0 <= p[1] < rig.height for p in (left, right))
        if not inside:
            continue
        row_errors.append(abs(left[1] - right[1]))
        disparity = left[0] - right[0]
        rectified_point = calibration.rectified_from_raw @ points[i]
        depth = rig.fx * rig.baseline_m / disparity
        depth_errors.append(abs(depth / rectified_point[2] - 1.0))
    assert len(row_errors) > 30
    assert max(row_errors) < 0.1  # rows aligned to a tenth of a pixel
    assert max(depth_errors) < 0.005  # Z = f B / d holds in the rectified frame

    # The same points through OpenCV's own inverse (undistortPoints) agree with our tables.
    expected = cv2.undistortPoints(
        raw_left,
        np.array(K1),
        np.array(D1),
        R=calibration.rectified_from_raw,
        P=np.array([[rig.fx, 0, rig.cx, 0], [0, rig.fy, rig.cy, 0], [0, 0, 1, 0]]),
    )[:, 0]
    ours = np.array([to_rectified(0, raw_left[i, 0]) for i in range(5)])
    np.testing.assert_allclose(ours, expected[:5], atol=0.05)


def test_rectify_pair_applies_the_tables(tmp_path: Path) -> None:
    calibration = load_calibration(write_stereo(tmp_path))
    image = np.zeros((480, 640), dtype=np.uint8)
    cv2.circle(image, (318, 243), 20, 255, -1)  # around the left principal point
    left, right = rectify_pair(image, image, calibration.maps)
    assert left.shape == (480, 640) and right.shape == (480, 640)
    ys, xs = np.nonzero(left > 128)
    assert abs(xs.mean() - calibration.rig.cx) < 3 and abs(ys.mean() - calibration.rig.cy) < 3
    same_left, same_right = rectify_pair(image, image, None)
    assert same_left is image and same_right is image


def test_swapped_cameras_are_rejected(tmp_path: Path) -> None:
    path = write_stereo(tmp_path)
    text = path.read_text().replace("- -0.11", "- 0.11")
    path.write_text(text)
    from avoidd.errors import ConfigError

    with pytest.raises(ConfigError, match="the right camera is on the left"):
        load_calibration(path)
