"""The daemon's YAML configuration as frozen, typed models (version 1), one module per section.

``avoidd.config`` re-exports every public name, so ``from avoidd.config import HeadConfig`` works
whichever module a model lives in.
"""

from avoidd.config.app import AppConfig, PipelineConfig, load_config
from avoidd.config.avoidance import AvoidanceConfig, GoalConfig
from avoidd.config.base import ConfigPath, Strict
from avoidd.config.connection import LinkSpec, parse_connection
from avoidd.config.debug_server import DebugServerConfig
from avoidd.config.head import HeadConfig, MountConfig
from avoidd.config.mavlink import (
    ControlConfig,
    DistanceSensorConfig,
    MavlinkConfig,
    ObstacleDistance3dConfig,
    ObstacleDistanceConfig,
    SigningConfig,
    StreamsConfig,
)
from avoidd.config.perception import (
    AttitudeConfig,
    BandConfig,
    GroundConfig,
    ObstaclesConfig,
    PerceptionConfig,
    TemporalConfig,
)
from avoidd.config.service import ServiceConfig
from avoidd.config.sources import (
    FilesSourceConfig,
    SimSourceConfig,
    SourceConfig,
    SyntheticObstacleConfig,
    SyntheticSourceConfig,
    V4l2SourceConfig,
)
from avoidd.config.stereo import (
    CensusConfig,
    DisparityRange,
    HistogramConfig,
    MatcherConfig,
    NearFieldConfig,
    PostprocessConfig,
    PreprocessConfig,
    SadConfig,
    SectorsConfig,
    SegmentConfig,
    SgbmConfig,
    TextureConfig,
)

__all__ = [
    "AppConfig",
    "AttitudeConfig",
    "AvoidanceConfig",
    "BandConfig",
    "CensusConfig",
    "ConfigPath",
    "ControlConfig",
    "DebugServerConfig",
    "DisparityRange",
    "DistanceSensorConfig",
    "FilesSourceConfig",
    "GoalConfig",
    "GroundConfig",
    "HeadConfig",
    "HistogramConfig",
    "LinkSpec",
    "MatcherConfig",
    "MavlinkConfig",
    "MountConfig",
    "NearFieldConfig",
    "ObstacleDistance3dConfig",
    "ObstacleDistanceConfig",
    "ObstaclesConfig",
    "PerceptionConfig",
    "PipelineConfig",
    "PostprocessConfig",
    "PreprocessConfig",
    "SadConfig",
    "SectorsConfig",
    "SegmentConfig",
    "ServiceConfig",
    "SgbmConfig",
    "SigningConfig",
    "SimSourceConfig",
    "SourceConfig",
    "StreamsConfig",
    "Strict",
    "SyntheticObstacleConfig",
    "SyntheticSourceConfig",
    "TemporalConfig",
    "TextureConfig",
    "V4l2SourceConfig",
    "load_config",
    "parse_connection",
]
