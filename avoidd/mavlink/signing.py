"""MAVLink 2 signing: the secret key and a signing timestamp that survives restarts.

The timestamp counts 10 microsecond units since 2015-01-01 00:00:00 UTC and must never go back,
or receivers drop our messages as replays. A companion computer often has no real-time clock,
so a high-water mark is kept in a file: the value written is always ahead of anything sent, and
a restart begins from it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from pathlib import Path

from avoidd.errors import ConfigError

logger = logging.getLogger(__name__)

SIGNING_KEY_BYTES = 32
EPOCH_2015_S = 1_420_070_400
UNITS_PER_S = 100_000
LEAD_S = 60
"""How far ahead of the timestamp in use the persisted high-water mark is kept."""


def parse_key(data: bytes, subject: str) -> bytes:
    """Read a signing key: 32 raw bytes, or 64 hexadecimal digits (whitespace ignored).

    Raises:
        ConfigError: Anything else, with how to make a valid key.
    """
    if len(data) == SIGNING_KEY_BYTES:
        return data
    text = data.decode("ascii", "replace").strip()
    if len(text) == 2 * SIGNING_KEY_BYTES:
        with contextlib.suppress(ValueError):
            return bytes.fromhex(text)
    raise ConfigError(
        [
            f"{subject}: not a MAVLink signing key (need 32 raw bytes or 64 hex digits, "
            f"got {len(data)} bytes); for a passphrase as QGroundControl and Mission Planner "
            "use it, write its SHA-256: printf %s PASSPHRASE | sha256sum | cut -c1-64 > FILE"
        ]
    )


def load_key(key_file: Path | None, credential: str | None) -> bytes:
    """Load the key from a file, or from systemd's ``$CREDENTIALS_DIRECTORY/<credential>``.

    Raises:
        ConfigError: The key cannot be found or read, naming the path and the remedy.
    """
    if credential is not None:
        directory = os.environ.get("CREDENTIALS_DIRECTORY")
        if not directory:
            raise ConfigError(
                [
                    f"mavlink.signing.key_credential '{credential}': $CREDENTIALS_DIRECTORY is "
                    "not set; run under systemd with LoadCredential= or use key_file"
                ]
            )
        path = Path(directory) / credential
    elif key_file is not None:
        path = key_file
    else:
        raise ConfigError(["mavlink.signing: set key_file or key_credential"])
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(
            [f"{path}: cannot read the signing key ({exc.strerror}); check path and permissions"]
        ) from exc
    return parse_key(data, str(path))


def wall_timestamp(now_s: float | None = None) -> int:
    """The signing timestamp of the wall clock (0 when the clock is before 2015)."""
    now_s = time.time() if now_s is None else now_s
    return max(int((now_s - EPOCH_2015_S) * UNITS_PER_S), 0)


class TimestampStore:
    """Keeps the signing high-water mark in a file.

    Args:
        path: The file (its folder must exist and be writable); None keeps nothing.
    """

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._reserved = 0

    def start(self, now_s: float | None = None) -> int:
        """The timestamp to start signing from: the wall clock, or the stored mark if later."""
        stored = 0
        if self.path is not None:
            try:
                stored = int(self.path.read_text().strip() or 0)
            except FileNotFoundError:
                stored = 0
            except (OSError, ValueError) as exc:
                logger.warning(
                    "signing timestamp %s unreadable (%s); using the clock", self.path, exc
                )
        start = max(wall_timestamp(now_s), stored)
        self.keep(start)
        return start

    def keep(self, timestamp: int) -> None:
        """Make sure the stored mark is ahead of ``timestamp`` (writes only when needed)."""
        if self.path is None or timestamp + LEAD_S * UNITS_PER_S // 2 < self._reserved:
            return
        reserved = timestamp + LEAD_S * UNITS_PER_S
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            with open(tmp, "w") as handle:
                handle.write(f"{reserved}\n")
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, self.path)
        except OSError as exc:
            logger.error("cannot store the signing timestamp in %s (%s)", self.path, exc)
            return
        self._reserved = reserved
