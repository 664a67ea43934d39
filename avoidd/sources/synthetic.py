"""The synthetic camera: a rendered scene, optionally moving toward the rig, with exact depth."""

from __future__ import annotations

import logging
import time

import numpy as np

from avoidd.config import SyntheticSourceConfig
from avoidd.sources.base import Pacer
from avoidd.sources.scene import Box, Pole, RenderedPair, Scene, render_pair, to_uint8
from avoidd.types import FloatArray, FramePose, RectifiedRig, StereoFrame

logger = logging.getLogger(__name__)

_STATIC_VARIANTS = 6


def approach_period_s(config: SyntheticSourceConfig) -> float:
    """How long one approach of a moving scene lasts before it starts over (0: static)."""
    if config.approach_speed_mps <= 0 or not config.obstacles:
        return 0.0
    nearest_m = min(o.forward_m - o.depth_m / 2 for o in config.obstacles)
    return max(nearest_m - config.min_forward_m, 0.0) / config.approach_speed_mps


def scene_at(config: SyntheticSourceConfig, t_s: float) -> Scene:
    """The scene at scene time ``t_s``: obstacles moved toward the rig at the approach speed.

    When the nearest obstacle would come closer than ``min_forward_m`` the approach starts over,
    so a moving scene loops forever.

    Args:
        config: The synthetic source configuration.
        t_s: Scene time in seconds (frame number divided by fps).

    Returns:
        The scene to render.
    """
    period_s = approach_period_s(config)
    shift_m = config.approach_speed_mps * (t_s % period_s) if period_s > 0 else 0.0
    obstacles: list[Box | Pole] = []
    for o in config.obstacles:
        forward = o.forward_m - shift_m
        if o.shape == "box":
            obstacles.append(Box(forward, o.right_m, o.depth_m, o.width_m, o.height_m))
        else:
            obstacles.append(Pole(forward, o.right_m, o.width_m, o.height_m))
    return Scene(
        camera_height_m=config.camera_height_m,
        camera_pitch_deg=config.camera_pitch_deg,
        obstacles=tuple(obstacles),
        backdrop_m=config.backdrop_m,
        seed=config.seed,
        vehicle_roll_deg=config.vehicle_roll_deg,
        vehicle_pitch_deg=config.vehicle_pitch_deg,
    )


class SyntheticSource:
    """Renders the configured scene as a rectified stereo camera.

    A static scene is rendered once and delivered with fresh sensor noise from a small bank of
    noisy variants; a moving scene is rendered for every frame.

    Args:
        config: The synthetic source configuration.
        rig: The rectified rig of the head (size, focal length, baseline).
        paced: Deliver frames at ``config.fps`` in real time (daemon) rather than as fast as
            possible with scene-time stamps (replay, tests).
    """

    def __init__(self, config: SyntheticSourceConfig, rig: RectifiedRig, paced: bool) -> None:
        self._config = config
        self._rig = rig
        self._pacer = Pacer(config.fps) if paced else None
        self._seq = 0
        self._warned_slow = not paced
        self._static: list[StereoFrame] = []
        if config.approach_speed_mps == 0:
            started = time.perf_counter()
            rendered = render_pair(scene_at(config, 0.0), rig)
            rng = np.random.default_rng(config.seed)
            self._static = [self._noisy(rendered, rng, 0) for _ in range(_STATIC_VARIANTS)]
            logger.info(
                "synthetic scene rendered in %.0f ms (%dx%d)",
                (time.perf_counter() - started) * 1000,
                rig.width,
                rig.height,
            )

    @property
    def description(self) -> str:
        """What the source reads, for logs and errors."""
        return f"synthetic scene (seed {self._config.seed})"

    def _noise(self, rng: np.random.Generator, shape: tuple[int, ...]) -> FloatArray | None:
        if self._config.noise_std == 0:
            return None
        return rng.normal(0.0, self._config.noise_std, shape).astype(np.float32)

    def _noisy(self, rendered: RenderedPair, rng: np.random.Generator, seq: int) -> StereoFrame:
        return StereoFrame(
            seq=seq,
            t_capture_ns=0,
            left=to_uint8(rendered.left, self._noise(rng, rendered.left.shape)),
            right=to_uint8(rendered.right, self._noise(rng, rendered.right.shape)),
            truth=rendered.truth,
            pose=FramePose(
                self._config.vehicle_roll_deg,
                self._config.vehicle_pitch_deg,
                self._config.camera_height_m,
                "synthetic",
                "synthetic",
            ),
        )

    def read(self) -> StereoFrame:
        """Deliver the next frame (never ends)."""
        seq = self._seq
        self._seq += 1
        t_scene_s = seq / self._config.fps
        if self._static:
            frame = self._static[seq % len(self._static)]._replace(seq=seq)
        else:
            started = time.perf_counter()
            rendered = render_pair(scene_at(self._config, t_scene_s), self._rig)
            rng = np.random.default_rng((self._config.seed, seq))
            frame = self._noisy(rendered, rng, seq)
            self._warn_if_slow(time.perf_counter() - started)
        if self._pacer is not None:
            t_capture_ns = self._pacer.wait()
        else:
            t_capture_ns = int(t_scene_s * 1e9)
        period_s = approach_period_s(self._config)
        restarts = int(t_scene_s // period_s) if period_s > 0 else 0
        return frame._replace(t_capture_ns=t_capture_ns, restarts=restarts)

    def _warn_if_slow(self, render_s: float) -> None:
        if self._warned_slow or render_s <= 1.0 / self._config.fps:
            return
        self._warned_slow = True
        logger.warning(
            "synthetic: a moving scene takes %.0f ms per frame at %dx%d, so it delivers about "
            "%.1f fps, not %.1f; lower fps or the resolution, or use replay",
            render_s * 1000,
            self._rig.width,
            self._rig.height,
            1.0 / render_s,
            self._config.fps,
        )

    def close(self) -> None:
        """Nothing to release."""
