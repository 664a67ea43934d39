"""The root of the configuration file (``AppConfig``), its pipeline section and ``load_config``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator

from avoidd.config.avoidance import AvoidanceConfig
from avoidd.config.base import Strict, WholeNumber
from avoidd.config.debug_server import DebugServerConfig
from avoidd.config.head import HeadConfig
from avoidd.config.mavlink import MavlinkConfig
from avoidd.config.perception import PerceptionConfig
from avoidd.config.service import ServiceConfig
from avoidd.yamlfile import load_yaml, validate_document


class PipelineConfig(Strict):
    """Daemon-wide timing.

    Attributes:
        max_age_ms: A scan older than this (from capture to send) is never sent; every bin goes
            out as unknown instead.
        log_interval_s: Period of the one-line status log (0.5 s to an hour).
        threads: Vision threads: 0 = one per CPU core. With 2 or more, each head matches its
            next frame while the previous one is post-processed (the stages overlap, the
            newest frame still wins and results keep their order), and OpenCV's matcher uses
            that many threads. 1 = one frame at a time on one thread (the least CPU).
        matcher_nice: With the stages overlapped: how much nicer (lower CPU priority) the
            matching thread runs than the rest of the daemon, so that the finishing thread,
            which holds the older frame, gets a core whenever it is ready and the matcher uses
            what is left (three busy threads on two cores otherwise share them evenly, and the
            older frame waits). 0: the same priority. Also lowers it against other programs on
            the computer; raising nice needs no privileges. See docs/stereo.md for figures.
    """

    max_age_ms: int = Field(300, ge=20, le=5000)
    log_interval_s: float = Field(5.0, ge=0.5, le=3600.0)
    threads: int = Field(0, ge=0, le=64)
    matcher_nice: int = Field(4, ge=0, le=19)


class AppConfig(Strict):
    """The whole configuration file.

    Attributes:
        version: Format version of the file; 1.
    """

    version: Annotated[Literal[1], WholeNumber]
    heads: list[HeadConfig] = Field(min_length=1, max_length=8)
    mavlink: MavlinkConfig = MavlinkConfig()
    pipeline: PipelineConfig = PipelineConfig()
    perception: PerceptionConfig = PerceptionConfig()
    avoidance: AvoidanceConfig = AvoidanceConfig()
    service: ServiceConfig = ServiceConfig()
    debug_server: DebugServerConfig = DebugServerConfig()

    @field_validator("heads")
    @classmethod
    def _unique_names(cls, value: list[HeadConfig]) -> list[HeadConfig]:
        names = [head.name for head in value]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise ValueError(f"head names must be unique; rename {', '.join(duplicates)}")
        return value


def load_config(path: Path, input_given: bool = False) -> AppConfig:
    """Load and validate a configuration file.

    Args:
        path: The YAML file.
        input_given: The command reads its own input (``--input``), so a ``files`` source's
            path need not exist.

    Returns:
        The validated configuration; relative paths in it are resolved against its folder.

    Raises:
        ConfigError: One line per problem, naming file, line, key path, value and remedy.
    """
    doc = load_yaml(path)
    context = {"base_dir": path.parent.resolve(), "input_given": input_given}
    return validate_document(doc, AppConfig, context)
