"""Free space on the data directory's file system, and the 507 answer when a write would not fit.

An upload, a job start and a job's artifacts all land under ``SCANMILL_DATA_DIR``. Before each,
:func:`check_free_space` asks the file system how much is free and refuses (507
``insufficient_storage``, naming the space needed, the space available and
``SCANMILL_MIN_FREE_DISK_MB``) when the write would leave less than that reserve.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from service.problems import ApiError
from service.settings import Settings

MIB = 1 << 20


def free_bytes(path: str | os.PathLike) -> int:
    """Bytes free for an unprivileged writer on the file system holding ``path`` (its nearest existing parent)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return int(shutil.disk_usage(p).free)


class InsufficientStorage(ApiError):
    """507 ``insufficient_storage``: the write of ``what`` needs more space than is free above the reserve."""

    def __init__(self, what: str, needed: int, free: int, reserve: int):
        super().__init__(
            507, "insufficient_storage",
            f"Not enough free disk space for {what}: it needs about {needed / MIB:,.0f} MiB and "
            f"{free / MIB:,.0f} MiB are free, of which SCANMILL_MIN_FREE_DISK_MB = {reserve // MIB:,} MiB are "
            "kept in reserve. Free space on the data directory (delete finished jobs) or try again later.",
            title="Insufficient storage", limit="SCANMILL_MIN_FREE_DISK_MB", limit_value=reserve // MIB,
            needed_bytes=int(needed), free_bytes=int(free))


def check_free_space(settings: Settings, needed_bytes: int, what: str, path: str | os.PathLike | None = None) -> int:
    """Raise :class:`InsufficientStorage` unless ``needed_bytes`` fit above the reserve; returns the free bytes."""
    free = free_bytes(path if path is not None else settings.data_dir)
    reserve = int(settings.min_free_disk_mb) * MIB
    if free - int(needed_bytes) < reserve:
        raise InsufficientStorage(what, int(needed_bytes), free, reserve)
    return free
