"""Signing a link as ``mavlink.signing`` says: the key, the allow-list, the stored timestamps."""

from __future__ import annotations

import asyncio

from avoidd.config.mavlink import SigningConfig
from avoidd.mavlink import codec as mav
from avoidd.mavlink.signing import KEEP_INTERVAL_S, TimestampStore, load_key


def sign_link(codec: mav.Codec, config: SigningConfig | None) -> TimestampStore:
    """Enable signing on ``codec`` when configured, starting from the stored timestamps.

    Args:
        codec: The link's codec.
        config: ``mavlink.signing`` (None: the link does not sign; nothing is kept).

    Returns:
        Where the timestamps are kept: call its ``keep`` every second or so, before acting on
        a command, and at stop.

    Raises:
        ConfigError: The key cannot be read.
    """
    if config is None:
        return TimestampStore(None)
    key = load_key(config.key_file, config.key_credential)
    allowed = {mav.message_id(name) for name in config.allow_unsigned}
    store = TimestampStore(config.timestamp_file)
    codec.enable_signing(key, store.start(), allowed.__contains__, config.link_id, store.streams)
    return store


async def keep_timestamps(codec: mav.Codec, store: TimestampStore) -> None:
    """Write the link's signing timestamps every :data:`KEEP_INTERVAL_S`, until cancelled."""
    while True:
        await asyncio.sleep(KEEP_INTERVAL_S)
        store.keep(codec.signing_timestamp)
