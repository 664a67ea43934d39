"""MAVLink 2 signing: the key, the check of incoming signatures, and state kept across restarts.

The timestamp counts 10 microsecond units since 2015-01-01 00:00:00 UTC. Ours must never go
back, or receivers drop our messages as replays; nor may it run far ahead of the autopilot's,
which takes a new sender (avoidd after a restart, say) only within a minute of its own clock
(pymavlink and ArduPilot both; avoidd's own check of a new sender is the same). A companion
computer often has no real-time clock, so the timestamp in use is written to a file every
second and a restart begins a few seconds past it: never behind what was sent, never a minute
ahead of it. The same file keeps the newest timestamp accepted from every signed sender, so a
message captured before a restart is refused after it as it is within one run.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import json
import logging
import os
import time
from pathlib import Path
from typing import Any

from avoidd.errors import ConfigError
from avoidd.fileread import UnreadableFile, read_bounded

logger = logging.getLogger(__name__)

SIGNING_KEY_BYTES = 32
EPOCH_2015_S = 1_420_070_400
UNITS_PER_S = 100_000
KEEP_INTERVAL_S = 1.0
"""How often the timestamp in use (and the senders' newest) is written while signing."""
RESTART_STEP_S = 3.0
"""A restart signs from this far past the stored timestamp (more than the time between two
writes, so nothing sent before the restart is signed with a timestamp used again)."""
NEW_STREAM_WINDOW = 60 * UNITS_PER_S
"""A sender not heard before is taken only if its timestamp is at most a minute behind ours
(MAVLink's rule)."""
_LEGACY_LEAD_S = 60
"""Files of earlier versions hold a mark this far ahead of the timestamp then in use."""

MAX_KEY_FILE_BYTES = 1024
"""A key file holds 32 bytes or 64 hex digits (and whitespace); more is no key file."""
MAX_TIMESTAMP_FILE_BYTES = 1_000_000
"""The timestamp file: ours and one line per signed sender, a few kilobytes at most."""

Stream = tuple[int, int, int]
"""A signed sender: (link id, system id, component id)."""


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
        data = read_bounded(path, MAX_KEY_FILE_BYTES)
    except FileNotFoundError as exc:
        raise ConfigError(
            [f"{path}: cannot read the signing key (no such file); check path and permissions"]
        ) from exc
    except UnreadableFile as exc:
        raise ConfigError(
            [
                f"{path}: cannot read the signing key: {exc.reason}; give a file of 32 raw "
                "bytes or 64 hex digits"
            ]
        ) from None
    return parse_key(data, str(path))


def wall_timestamp(now_s: float | None = None) -> int:
    """The signing timestamp of the wall clock (0 when the clock is before 2015)."""
    now_s = time.time() if now_s is None else now_s
    return max(int((now_s - EPOCH_2015_S) * UNITS_PER_S), 0)


class SignatureCheck:
    """Checks an incoming signed frame: the signature first, then its timestamp.

    pymavlink's own check records a frame's timestamp before it looks at the signature, so
    one forged frame with a timestamp far ahead would make every genuine frame of that sender
    "old"; and each parser kept its own record, so a captured frame sent again from another
    address was a new sender. Here only frames with a valid signature count, and the record
    (``streams``) is one per link, shared by every parser and kept across restarts.

    Args:
        key: The 32-byte secret key.
        state: pymavlink's signing state of the link (its ``timestamp`` follows the newest
            timestamp accepted, as MAVLink asks).
        streams: The newest timestamp accepted per sender (updated in place).

    Attributes:
        replays: Frames refused because their sender had already sent a newer or equal one.
        stale: Frames of a sender not heard before, more than a minute behind our timestamp.
        mismatches: Frames whose signature is not the key's.
    """

    def __init__(self, key: bytes, state: Any, streams: dict[Stream, int]) -> None:
        self.key = key
        self.state = state
        self.streams = streams
        self.replays = 0
        self.stale = 0
        self.mismatches = 0

    def __call__(self, msgbuf: bytes | bytearray, src_system: int, src_component: int) -> bool:
        """Whether the frame ``msgbuf`` (whole, signature included) is to be accepted."""
        frame = bytes(msgbuf)
        if len(frame) < 13:
            self.mismatches += 1
            return False
        expected = hashlib.sha256(self.key + frame[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, frame[-6:]):
            self.mismatches += 1
            return False
        timestamp = int.from_bytes(frame[-12:-6], "little")
        stream = (frame[-13], src_system, src_component)
        newest = self.streams.get(stream)
        if newest is not None and timestamp <= newest:
            self.replays += 1
            return False
        if newest is None and timestamp + NEW_STREAM_WINDOW < self.state.timestamp:
            self.stale += 1
            return False
        self.streams[stream] = timestamp
        self.state.timestamp = max(self.state.timestamp, timestamp)
        return True


class TimestampStore:
    """Keeps the signing timestamp in use, and the newest one of every signed sender, in a file.

    The file is JSON: ``{"timestamp": T, "streams": {"LINK:SYSTEM:COMPONENT": T, ...}}``. A
    file of an earlier version holds one number, a mark 60 s ahead of the timestamp then in
    use; it is read as that timestamp.

    Args:
        path: The file (its folder must exist and be writable); None keeps nothing.
    """

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.streams: dict[Stream, int] = {}
        """The newest timestamp accepted per sender: read by :meth:`start`, shared with the
        link's :class:`SignatureCheck`, written by :meth:`keep`."""
        self._written: tuple[int, dict[Stream, int]] | None = None
        self._written_s = -1e18

    def start(self, now_s: float | None = None) -> int:
        """The timestamp to start signing from: the wall clock, or a little past the stored one.

        Also reads the senders' newest timestamps into :attr:`streams`.
        """
        stored = self._read()
        start = wall_timestamp(now_s)
        if stored is not None:
            start = max(start, stored + int(RESTART_STEP_S * UNITS_PER_S))
        self.keep(start, force=True)
        return start

    def _read(self) -> int | None:
        if self.path is None:
            return None
        try:
            text = read_bounded(self.path, MAX_TIMESTAMP_FILE_BYTES).decode("utf-8")
        except FileNotFoundError:
            return None
        except (UnreadableFile, UnicodeDecodeError) as exc:
            logger.warning("signing timestamp %s unreadable (%s); using the clock", self.path, exc)
            return None
        try:
            data = json.loads(text)
        except ValueError:
            data = None
        if isinstance(data, int) and not isinstance(data, bool):
            return max(data - _LEGACY_LEAD_S * UNITS_PER_S, 0)
        if isinstance(data, dict) and isinstance(data.get("timestamp"), int):
            self.streams = _streams(data.get("streams"))
            return int(data["timestamp"])
        logger.warning(
            "signing timestamp %s is not avoidd's (a number, or JSON with 'timestamp'); "
            "using the clock",
            self.path,
        )
        return None

    def keep(self, timestamp: int, force: bool = False) -> None:
        """Write ``timestamp`` (the one in use) and the senders' newest, if they changed.

        At most once per :data:`KEEP_INTERVAL_S` unless ``force`` (at start, at stop, and
        before a command is acted on, so that it cannot be replayed after a crash).
        """
        if self.path is None:
            return
        now_s = time.monotonic()
        if not force and now_s - self._written_s < KEEP_INTERVAL_S:
            return
        written = self._written
        if written is not None and written[0] == timestamp and written[1] == self.streams:
            return
        record = {
            "timestamp": timestamp,
            "streams": {f"{a}:{b}:{c}": t for (a, b, c), t in sorted(self.streams.items())},
        }
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            with open(tmp, "w") as handle:
                handle.write(json.dumps(record) + "\n")
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, self.path)
        except OSError as exc:
            logger.error("cannot store the signing timestamp in %s (%s)", self.path, exc)
            return
        self._written = (timestamp, dict(self.streams))
        self._written_s = now_s


def _streams(raw: object) -> dict[Stream, int]:
    """The senders' newest timestamps from the file (entries that do not parse are dropped)."""
    streams: dict[Stream, int] = {}
    if not isinstance(raw, dict):
        return streams
    for name, value in raw.items():
        parts = str(name).split(":")
        if len(parts) != 3 or not isinstance(value, int) or isinstance(value, bool):
            continue
        with contextlib.suppress(ValueError):
            link_id, system, component = (int(part) for part in parts)
            streams[(link_id, system, component)] = value
    return streams
