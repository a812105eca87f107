"""The jobs API contract: job resources, requests, artifacts and RFC 9457 problem documents.

These pydantic models are the HTTP API of ``scanmill serve`` (``service/``): FastAPI builds the
OpenAPI document from them, and the generated clients are built from that document. The plan
configuration of a job is :class:`schemas.params.PlanConfig` (docs/design.md parameter names) and the
finished plan is :class:`schemas.plan.PlanResult` (``plan.json``); this module only adds what a job
around them needs. Times are RFC 3339 in UTC; durations carry ``_s``, sizes ``_bytes``.
"""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.params import PlanConfig

API_VERSION = "1"

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
#: Statuses of a job that is done: its worker has stopped and its files no longer change.
FINISHED_STATUSES: tuple[str, ...] = ("succeeded", "failed", "cancelled")
#: The stages a running job goes through, in order ("read" the cloud, the pipeline's, "write"); "placement" runs
#: with fixtures.placement = auto (and after "setups" for the hint of an infeasible as-scanned plan).
JOB_STAGES: tuple[str, ...] = ("read", "normals", "placement", "orientations", "visibility", "setups", "areas", "paths",
                               "post", "simulate", "write")
CloudFormat = Literal["ply", "pcd", "xyz", "csv", "txt", "stl", "obj", "las", "laz", "e57", "png", "jpg", "jpeg", "bmp",
                      "tif", "tiff"]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class JobError(_Model):
    """Why a job failed or was stopped: a stable code and a sentence for the operator."""

    code: str = Field(..., description="Stable machine-readable code, e.g. 'non_finite', 'time_limit_exceeded', "
                                       "'interrupted', 'worker_crashed'.", examples=["non_finite"])
    message: str = Field(..., description="What happened and what to do about it.")


class JobInput(_Model):
    """What was submitted: the cloud as read at submission, and the fixture files."""

    name: str | None = Field(None, description="File name of the submitted cloud (or the inline cloud's name).")
    format: str = Field(..., description="Detected file format, e.g. 'ply-binary_little_endian'.")
    size_bytes: int = Field(..., ge=0, description="Size of the stored cloud file.")
    n_points: int = Field(..., ge=1, description="Points in the cloud.")
    has_normals: bool = Field(..., description="Whether the file carries normals (needed by normals.method=input).")
    sha256: str = Field(..., description="SHA-256 of the stored cloud file (hex).")
    fixtures: list[str] = Field(default_factory=list, description="Stored fixture file names.")


class JobResultSummary(_Model):
    """The headline of a finished plan; the whole plan is at ``links.result``."""

    status: str = Field(..., description="plan.json 'status': 'planned', 'unfinished', 'infeasible' or 'incomplete'.",
                        examples=["planned"])
    message: str = Field(..., description="plan.json 'message': one sentence for the operator.")
    finished_share: float | None = Field(
        None, ge=0, le=1, description="plan.json 'figures.finished_share': the share of the scan's input points the "
                                      "simulated programs finish within tolerance (null: not simulated).")
    machining_time_s: float | None = Field(None, ge=0, description="plan.json 'figures.machining_time_s', s.")
    time_source: str | None = Field(None, description="plan.json 'figures.time_source': 'simulated' or 'estimate'.")
    n_setups: int = Field(..., ge=0, description="Number of set-ups (fixed tool orientations).")
    coverage: float = Field(..., ge=0, le=1, description="Fraction of sampled points the set-ups see.")
    overlap_points: int = Field(..., ge=0, description="Sampled points seen by two or more chosen set-ups.")
    verification: Literal["passed", "failed", "skipped"] | None = Field(
        None, description="plan.json 'verification.status': the programs run on a simulated machine and stock; "
                          "'failed' means a program would harm the machine, the tool or the part (the job itself "
                          "succeeded: the plan and its verdict are the result).")
    verification_message: str | None = Field(None, description="plan.json 'verification.message': why, one line "
                                                               "per class of offence.")


class JobLinks(_Model):
    """Where to go next (absolute paths on this service)."""

    self: str = Field(..., description="This job.", examples=["/jobs/3f2b0c3e9a1d4b7c8e6f5a4b3c2d1e0f"])
    result: str | None = Field(None, description="plan.json, once the job has succeeded.")
    artifacts: str | None = Field(None, description="The list of artifacts, once the job has succeeded.")


class Job(_Model):
    """A planning job: its state, progress, inputs and, once finished, its outcome."""

    id: str = Field(..., description="Job identifier (32 hex digits).", examples=["3f2b0c3e9a1d4b7c8e6f5a4b3c2d1e0f"])
    status: JobStatus = Field(..., description="queued -> running -> succeeded | failed; cancelled by DELETE.")
    stage: str | None = Field(None, description="Current (or last) stage: read, normals, orientations, visibility, "
                                                "setups, areas, paths, post, simulate, write (later versions may add "
                                                "stages).",
                              examples=["visibility"])
    progress: float = Field(..., ge=0, le=1, description="Fraction of the whole job done, 0..1.")
    message: str | None = Field(None, description="Latest progress message.")
    created_at: datetime = Field(..., description="When the job was accepted (UTC).")
    started_at: datetime | None = Field(None, description="When its latest attempt started (UTC).")
    finished_at: datetime | None = Field(None, description="When it succeeded, failed or was cancelled (UTC).")
    updated_at: datetime = Field(..., description="Last change of this resource (UTC).")
    attempts: int = Field(..., ge=0, description="Times a worker started this job (a restart of the service "
                                                 "while it ran starts it again, up to a limit).")
    time_limit_s: float = Field(..., gt=0, description="Wall-clock limit of one attempt, seconds.")
    input: JobInput
    parameters: PlanConfig = Field(..., description="The validated plan configuration, defaults filled in.")
    error: JobError | None = Field(None, description="Set when the job failed or was cancelled.")
    result: JobResultSummary | None = Field(None, description="Set when the job succeeded.")
    warnings: list[str] = Field(default_factory=list, description="Things the operator should know.")
    links: JobLinks


class JobPage(_Model):
    """One page of jobs, newest first."""

    items: list[Job]
    next_cursor: str | None = Field(None, description="Pass as ?cursor= to get the next page; null on the last page.")
    links: dict[str, str] = Field(default_factory=dict, description="'self' and, if there is one, 'next'.")


class Artifact(_Model):
    """A file a finished job produced."""

    name: str = Field(..., examples=["plan.npz"])
    media_type: str = Field(..., examples=["application/octet-stream"])
    size_bytes: int = Field(..., ge=0)
    href: str = Field(..., examples=["/jobs/3f2b0c3e9a1d4b7c8e6f5a4b3c2d1e0f/artifacts/plan.npz"])


class ArtifactList(_Model):
    """The artifacts of a succeeded job: plan.json, plan.npz, segmentation PLY, preview PNG, G-code per area."""

    job_id: str
    items: list[Artifact]


class InlineCloud(_Model):
    """A small cloud sent inside a JSON request: points in the unit of ``parameters.input.units``."""

    points: list[tuple[float, float, float]] = Field(
        ..., min_length=1, description="(x, y, z) rows. The service bounds the count (SCANMILL_MAX_INLINE_POINTS; "
                                       "larger clouds go as a multipart file upload).")
    normals: list[tuple[float, float, float]] | None = Field(
        None, description="Optional (nx, ny, nz) rows, one per point (for normals.method = input).")


class JobCreateRequest(_Model):
    """``POST /jobs`` as ``application/json``: a small inline cloud and the plan configuration."""

    cloud: InlineCloud
    parameters: PlanConfig = Field(default_factory=PlanConfig,
                                   description="Plan configuration (docs/design.md names); omitted groups take defaults.")
    name: str | None = Field(None, max_length=200, description="A name for the cloud, reported in plan.json.")
    time_limit_s: float | None = Field(None, gt=0, description="Wall-clock limit of the job, seconds; at most the "
                                                               "service's limit (the default).")


class Problem(BaseModel):
    """An RFC 9457 problem document (``application/problem+json``); every error of the API is one."""

    model_config = ConfigDict(extra="allow")

    type: str = Field("about:blank", description="URI reference identifying the problem type.")
    title: str = Field(..., description="Short summary of the problem type.")
    status: int = Field(..., ge=400, le=599, description="The HTTP status code.")
    detail: str | None = Field(None, description="What went wrong with this request, and how to fix it.")
    instance: str | None = Field(None, description="The request path.")
    code: str = Field(..., description="Stable machine-readable code, e.g. 'too_many_points', 'invalid_parameter'.")
    errors: list[str] | None = Field(None, description="One entry per invalid parameter or field, naming it.")
    limit: str | None = Field(None, description="Name of the limit that was exceeded (e.g. SCANMILL_MAX_UPLOAD_BYTES).")
    limit_value: float | None = Field(None, description="The value of that limit.")
    job_status: JobStatus | None = Field(None, description="For conflicts on a job: its current status.")


class DiskHealth(_Model):
    """Free space on the data directory's file system, against the reserve SCANMILL_MIN_FREE_DISK_MB."""

    status: Literal["ok", "low", "unknown"] = Field(
        ..., description="'low': less free than the reserve (uploads and job starts are refused with 507); "
                         "'unknown': the file system could not be asked (also 'degraded').")
    free_bytes: int | None = Field(None, ge=0, description="Bytes free for the service.")
    min_free_bytes: int = Field(..., ge=0, description="The reserve, SCANMILL_MIN_FREE_DISK_MB, in bytes.")


class Health(_Model):
    """Liveness and readiness of the service."""

    status: Literal["ok", "degraded"] = Field(
        ..., description="'ok', or 'degraded' when the service answers but cannot take new work (the disk is "
                         "below its reserve, or its free space cannot be read): reads still work, submissions "
                         "are refused with 507.")
    workers: int = Field(..., ge=0, description="Job slots: this server's worker pool (embedded), or the total pool "
                                                "size of the Celery workers that answered the API's last census "
                                                "(at most 30 s old; 0 while the broker is unreachable).")
    busy_workers: int = Field(..., ge=0, description="Jobs running (on this server's pool, or on any Celery worker).")
    queued_jobs: int = Field(..., ge=0)
    running_jobs: int = Field(..., ge=0)
    disk: DiskHealth | None = Field(None, description="Free space of the data directory.")
    database: Literal["ok"] | None = Field(None, description="The job store answers ('ok'); when it does not, "
                                                             "/healthz answers 503 store_unavailable.")


class Version(_Model):
    """What is serving."""

    name: Literal["scanmill"] = "scanmill"
    version: str = Field(..., description="scanmill package version.")
    api_version: str = Field(API_VERSION, description="Version of this HTTP API.")
    plan_schema_version: str = Field(..., description="schema_version of the plan.json documents produced.")
