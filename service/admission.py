"""Admission: refuse at submission a job that could not run within its memory budget.

A plan's memory is set by its parameters as much as by its cloud: a fine orientation grid
(``orientations.phi_step_deg = 0.01`` gives 216,000 candidate axes) makes the visibility matrix and
the set-up search grow past any host's memory on a 2,537-point cloud. :func:`check_job_budget`
estimates the job's memory from the point count and the parameters
(:func:`planning.budget.estimate_job_memory`, microseconds, no planning run) and answers
``422 job_too_large`` when the estimate exceeds ``SCANMILL_JOB_MEMORY_MB``, naming the parameter that
drives it. The worker enforces the same budget as a hard limit (:mod:`service.memlimit`) for the
jobs the estimate lets through.
"""

from __future__ import annotations

from collections.abc import Sequence

from planning.budget import MemoryEstimate, estimate_job_memory
from schemas.params import PlanConfig
from service.problems import ApiError
from service.settings import Settings

MIB = 1 << 20


class JobTooLarge(ApiError):
    """422 ``job_too_large``: the job's memory estimate exceeds ``SCANMILL_JOB_MEMORY_MB``."""

    def __init__(self, estimate: MemoryEstimate, limit_mb: int):
        top = estimate.terms[0]
        est_mb = int(-(-estimate.total_bytes // MIB))
        super().__init__(
            422, "job_too_large",
            f"This job would need about {est_mb:,} MiB of memory, more than the {int(limit_mb):,} MiB one job may "
            f"use on this service (SCANMILL_JOB_MEMORY_MB). Most of it, about {top.mib:,.0f} MiB, is "
            f"{top.what}, driven by {top.driver}. {top.advice} Then submit it again.",
            title="Job too large", limit="SCANMILL_JOB_MEMORY_MB", limit_value=int(limit_mb), estimate_mb=est_mb,
            parameter=top.parameter,
            errors=[(f"{top.parameter}: the job's memory estimate ({est_mb:,} MiB) exceeds SCANMILL_JOB_MEMORY_MB "
                     f"= {int(limit_mb):,} MiB")])
        self.estimate = estimate


def check_job_budget(config: PlanConfig, n_points: int, settings: Settings, *,
                     extent_mm: Sequence[float] | None = None) -> MemoryEstimate:
    """Raise :class:`JobTooLarge` (422 ``job_too_large``) when the job's memory estimate exceeds the limit.

    ``n_points``: the points of the submitted cloud; ``extent_mm``: its bounding-box sides (x, y, z)
    in mm, which sharpen the raster terms (without them the configuration's
    ``input.max_extent_mm`` is assumed, an upper bound). Returns the estimate when it fits.
    """
    estimate = estimate_job_memory(n_points, config, extent_mm=extent_mm)
    limit_mb = int(settings.job_memory_limit_mb)
    if estimate.total_bytes > limit_mb * MIB:
        raise JobTooLarge(estimate, limit_mb)
    return estimate
