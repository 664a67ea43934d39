"""The service section: what avoidd tells systemd (readiness wait, status period, stall limit)."""

from __future__ import annotations

from pydantic import Field

from avoidd.config.base import Strict


class ServiceConfig(Strict):
    """Readiness, status and watchdog under a service manager (used only with ``NOTIFY_SOCKET``).

    Attributes:
        ready_timeout_s: ``READY=1`` goes out once every head has produced a result; after
            this long it goes out anyway, with a ``STATUS=`` and an error in the log naming what
            is missing (a drone's avoidd waiting for a camera keeps reporting, rather than
            being killed by systemd's start timeout). Keep it below ``TimeoutStartSec=``.
        status_interval_s: Period of the ``STATUS=`` line (rates, link, health).
        stall_s: A head is stuck when frames wait and its compute has finished none for this
            long, or when its source's read has not returned for this long; while any head is
            stuck, ``WATCHDOG=1`` is withheld, so systemd restarts avoidd after ``WatchdogSec=``.
    """

    ready_timeout_s: float = Field(10.0, ge=0.5, le=600.0)
    status_interval_s: float = Field(2.0, ge=0.5, le=3600.0)
    stall_s: float = Field(5.0, ge=0.5, le=600.0)
