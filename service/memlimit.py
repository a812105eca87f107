"""The memory limit a job runs under: an address-space limit (``RLIMIT_AS``) set in the job's own process.

A job whose estimate was wrong must fail alone, never take the host: :func:`apply_job_memory_limit`
caps the address space of the current process (a worker child that runs exactly one job at a time)
at what it already maps plus the job's budget, ``SCANMILL_JOB_MEMORY_MB``. An allocation past it
raises :class:`MemoryError` in the job, which the worker reports as ``memory_limit_exceeded`` with
:func:`memory_limit_message` (:func:`is_memory_exhaustion` also recognises the other ways running
out of address space shows: a thread that cannot start, a shared library that cannot be mapped).
Linux only (elsewhere it does nothing and says so).

The limit counts address space, not resident memory. To keep the two close, the process is first
told to use at most :data:`MALLOC_ARENAS` malloc arenas (glibc reserves 64 MiB of address space for
each thread's arena otherwise, most of it never used); the budget itself should come from
:func:`planning.budget.estimate_job_memory`, which is calibrated on the address space a job adds.
"""

from __future__ import annotations

import errno
import logging
import resource
import sys

MIB = 1 << 20
#: malloc arenas a limited job process may use (glibc's ``M_ARENA_MAX``).
MALLOC_ARENAS = 1
_M_ARENA_MAX = -8            # glibc's mallopt parameter number

log = logging.getLogger("scanmill.service")
_applied_mb: int | None = None


def mapped_bytes() -> int:
    """Virtual memory the current process maps now, bytes (``VmSize``; 0 when unknown)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _limit_malloc_arenas(n: int) -> bool:
    """Ask glibc to create at most ``n`` malloc arenas (each reserves 64 MiB of address space)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes
        libc = ctypes.CDLL(None)
        return bool(libc.mallopt(_M_ARENA_MAX, int(n)))
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return False


def apply_job_memory_limit(limit_mb: int) -> int | None:
    """Cap this process's address space at what it maps now plus ``limit_mb`` MiB; returns the cap in bytes.

    Called once at the start of a job's process (the embedded worker child, a Celery pool child),
    before the job reads its cloud. Returns None where the platform has no ``RLIMIT_AS`` or no
    ``/proc`` (the limit is then not applied, and :func:`applied_limit_mb` stays None).
    """
    global _applied_mb
    base = mapped_bytes()
    if not base or not hasattr(resource, "RLIMIT_AS"):
        log.warning("the job memory limit (SCANMILL_JOB_MEMORY_MB = %s) cannot be applied on this platform",
                    limit_mb)
        return None
    _limit_malloc_arenas(MALLOC_ARENAS)
    cap = base + int(limit_mb) * MIB
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    _applied_mb = int(limit_mb)
    return cap


def applied_limit_mb() -> int | None:
    """The limit :func:`apply_job_memory_limit` set in this process, MiB (None when none was set)."""
    return _applied_mb


def is_memory_exhaustion(exc: BaseException) -> bool:
    """Whether ``exc`` is how running out of memory (or of the address-space limit) shows in Python code.

    :class:`MemoryError` (numpy's ``_ArrayMemoryError`` included), an :class:`OSError` with
    ``ENOMEM``, a thread that cannot start (its stack cannot be mapped), a C++ allocation failure
    (``bad_alloc``) and a shared library that cannot be mapped while being imported.
    """
    if isinstance(exc, MemoryError):
        return True
    if isinstance(exc, OSError) and exc.errno == errno.ENOMEM:
        return True
    text = str(exc).lower()
    if isinstance(exc, RuntimeError) and ("can't start new thread" in text or "bad_alloc" in text):
        return True
    return isinstance(exc, ImportError) and ("cannot allocate memory" in text or "failed to map segment" in text)


def memory_limit_message(limit_mb: int) -> str:
    """What a job that ran out of its memory budget reports."""
    return (f"the job needed more memory than its limit, SCANMILL_JOB_MEMORY_MB = {int(limit_mb):,} MiB: "
            "coarsen orientations.phi_step_deg / theta_step_deg, decimate the cloud, or raise the limit")
