"""The process's open-files limit: raised to the hard one, since cameras, link and view share it.

Many systems start a service with a soft limit of 1,024 descriptors and a hard one far above
it. Each camera, the link, the debug view's connections and the vision threads' files come
out of the same budget; running out takes the camera away. Raising the soft limit to the hard
one costs nothing (systemd's ``LimitNOFILE=`` in the unit sets both).
"""

from __future__ import annotations

import logging
import resource

logger = logging.getLogger(__name__)

WANTED_FILES = 16384
"""Open files avoidd asks for (the unit's ``LimitNOFILE=``); more is not needed."""


def raise_open_files_limit(wanted: int = WANTED_FILES) -> int:
    """Raise the soft ``RLIMIT_NOFILE`` toward ``wanted``, within the hard limit.

    Returns:
        The soft limit now in effect.
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
    if soft != resource.RLIM_INFINITY and soft < target:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (ValueError, OSError) as exc:
            logger.debug("open files limit left at %d: %s", soft, exc)
    if soft < 1024:
        logger.warning(
            "open files limit is %d; cameras, link and debug view may run short "
            "(systemd: LimitNOFILE=%d)",
            soft,
            wanted,
        )
    return int(soft)
