"""The daemon: capture threads, compute workers, the MAVLink send loops, health and shutdown.

Modules, one job each: :mod:`.head` (a camera head at run time), :mod:`.framecheck` (frames
that carry no news: frozen, blind), :mod:`.announce` (operator STATUSTEXT), :mod:`.health` (pure
freshness rules), :mod:`.outputs` (obstacle messages), :mod:`.stats` (the counters snapshot
and log line) and :mod:`.core` (the :class:`Daemon` that composes them, supervises the tasks
and owns the shutdown order).
"""

from avoidd.daemon.announce import Announcer
from avoidd.daemon.core import Daemon, build_link
from avoidd.daemon.head import Head, HeadStats, OpenSource
from avoidd.daemon.stats import DaemonStats

__all__ = ["Announcer", "Daemon", "DaemonStats", "Head", "HeadStats", "OpenSource", "build_link"]
