"""A stranger's flood for ``bench-link --stranger``: one packed message sent at a rate, no more.

Run as its own process (``python -m avoidd.bench.flood PORT RATE SECONDS``), so that sending
costs the measured process nothing: the mock autopilot packs each message and reaches about
4,000 a second, this sends a copy of one frame and reaches 20,000 and more.
"""

from __future__ import annotations

import socket
import sys
import time

from avoidd.mavlink.codec import Codec


def flood(port: int, rate_hz: float, seconds: float) -> int:
    """Send ATTITUDE frames to 127.0.0.1:``port`` at ``rate_hz`` for ``seconds``.

    Returns:
        The datagrams sent (at most ``rate_hz * seconds``; fewer if sending falls behind for
        longer than twice the time).
    """
    codec = Codec(7, 1)
    frame = codec.pack(codec.build("ATTITUDE", 1000, 0.1, 0.1, 0.1, 0.0, 0.0, 0.0))
    total = int(rate_hz * seconds)
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        start_s = time.monotonic()
        while sent < total and time.monotonic() - start_s < 2 * seconds:
            due = min(int((time.monotonic() - start_s) * rate_hz), total)
            while sent < due:
                sock.sendto(frame, ("127.0.0.1", port))
                sent += 1
            time.sleep(0.001)
    return sent


if __name__ == "__main__":
    print(flood(int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])))
