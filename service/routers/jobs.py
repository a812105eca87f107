"""``/jobs`` routes: submit, read, list, cancel/delete, result and artifacts (tags ``jobs``, ``artifacts``).

Each route authenticates the caller, calls :class:`service.jobs.JobService` and shapes the HTTP
answer. Blocking work (files, listing, cancelling, deleting) runs in FastAPI's thread pool (plain
``def`` routes); the upload route awaits its I/O and reads the cloud in a worker thread; planning
runs in worker processes. ``GET /jobs/{id}``, the route pollers hit, reads its one SQLite row on
the event loop.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Header, Query, Request, Response
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse

from schemas.api import ArtifactList, Job, JobPage, JobStatus
from schemas.plan import PlanResult
from service.deps import Principal, get_jobs, get_principal
from service.jobs import JobService
from service.openapi import CREATE_JOB_REQUEST_BODY, EXAMPLE_JOB, problem_responses
from service.storage import accepts_gzip, iter_gunzipped, media_type

router = APIRouter(prefix="/jobs")

Caller = Annotated[Principal, Depends(get_principal)]
Jobs = Annotated[JobService, Depends(get_jobs)]


def _job_json(job: Job, status: int, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse(job.model_dump(mode="json", by_alias=True), status_code=status, headers=headers)


@router.post(
    "", operation_id="create_job", tags=["jobs"], status_code=202, response_model=Job,
    summary="Submit a scan for planning",
    description="Multipart: the scan as file field `cloud`, the plan configuration as JSON text field "
                "`parameters`, optional `name`, `format`, `time_limit_s` and `fixtures`. JSON: a small inline "
                "cloud (JobCreateRequest). The cloud is read and checked before the job is accepted. Answers 202 "
                "with `Location: /jobs/{id}`. With an `Idempotency-Key` header, the same key and body give back the "
                "same job (header `Idempotent-Replayed: true`); the same key with another body is refused (422).",
    openapi_extra={"requestBody": CREATE_JOB_REQUEST_BODY},
    responses={202: {"description": "Accepted: the job is queued.",
                     "headers": {"Location": {"schema": {"type": "string"}, "description": "/jobs/{id}"}},
                     "content": {"application/json": {"example": {**EXAMPLE_JOB, "status": "queued", "stage": None,
                                                                  "progress": 0.0, "started_at": None}}}},
               **problem_responses(400, 401, 403, 408, 413, 415, 422, 429, 507)})
async def create_job(request: Request, who: Caller, jobs: Jobs,
                     idempotency_key: Annotated[str | None, Header(
                         alias="Idempotency-Key", max_length=255,
                         description="Client-chosen key (e.g. a UUID) making the submission safe to retry.")] = None):
    job, replayed = await jobs.submit(request, who, idempotency_key)
    headers = {"Location": f"/jobs/{job.id}"}
    if replayed:
        headers["Idempotent-Replayed"] = "true"
    return _job_json(job, 202, headers)


@router.get("", operation_id="list_jobs", tags=["jobs"], response_model=JobPage, summary="List your jobs",
            description="Newest first, `limit` per page; follow `next_cursor` (or `links.next`). Filter by `status`.",
            responses=problem_responses(401, 403, 422))
def list_jobs(who: Caller, jobs: Jobs,
              status: Annotated[JobStatus | None, Query(description="Only jobs with this status.")] = None,
              limit: Annotated[int, Query(ge=1, le=100, description="Jobs per page.")] = 20,
              cursor: Annotated[str | None, Query(max_length=64, description="From a previous page.")] = None):
    return jobs.list(who, status, limit, cursor)


@router.get("/{job_id}", operation_id="get_job", tags=["jobs"], response_model=Job, summary="A job's state",
            description="Status, current stage, progress 0..1, times, error and links.",
            responses={200: {"content": {"application/json": {"example": EXAMPLE_JOB}}},
                       **problem_responses(401, 403, 404)})
async def get_job(job_id: str, who: Caller, jobs: Jobs):
    # The one route answered on the event loop: a single indexed SQLite read (~0.05 ms; WAL readers never wait
    # for the writer). Pollers hit it hardest, and a thread-pool hop costs more than the read itself.
    return jobs.get(job_id, who)


@router.delete("/{job_id}", operation_id="delete_job", tags=["jobs"], summary="Cancel or delete a job",
               description="A queued or running job is cancelled: its worker process is stopped and its files "
                           "(upload, artifacts) are removed before the answer (200, the cancelled job, which stays "
                           "readable until deleted). A finished job (succeeded, failed, cancelled) is deleted with "
                           "its files (204).",
               responses={200: {"description": "Cancelled.", "model": Job},
                          204: {"description": "Deleted with its files."},
                          **problem_responses(401, 403, 404, 409)})
def delete_job(job_id: str, who: Caller, jobs: Jobs):
    job = jobs.delete(job_id, who)
    if job is None:
        return Response(status_code=204)
    return _job_json(job, 200)


@router.get("/{job_id}/result", operation_id="get_job_result", tags=["jobs"], summary="The plan (plan.json)",
            description="The finished plan; 409 until the job has succeeded.",
            response_model=PlanResult, responses=problem_responses(401, 403, 404, 409))
def get_job_result(job_id: str, who: Caller, jobs: Jobs):
    return FileResponse(jobs.result_path(job_id, who), media_type="application/json")


@router.get("/{job_id}/artifacts", operation_id="list_artifacts", tags=["artifacts"], response_model=ArtifactList,
            summary="The files a job produced",
            description="plan.json, plan.npz, segmentation.ply, preview.png and, once tool paths exist, G-code per "
                        "area.", responses=problem_responses(401, 403, 404, 409))
def list_artifacts(job_id: str, who: Caller, jobs: Jobs):
    return jobs.artifacts(job_id, who)


_GET_ARTIFACT_DESCRIPTION = (
    "A file of GET /jobs/{id}/artifacts, as stored, with the media type of its extension "
    "(`.json.gz` is `application/gzip`, sent as is, no Content-Encoding). The neutral moves of each area are "
    "stored as `area_<i>.moves.json.gz` (the JSON, gzip compressed) and `area_<i>.moves.npz` (the same moves "
    "as arrays). For clients of plans before that, the old name `area_<i>.moves.json` (any `X.json` whose "
    "stored file is `X.json.gz`) still answers with the JSON, `application/json`: with `Content-Encoding: "
    "gzip` (the stored bytes) when the request's `Accept-Encoding` admits gzip (`gzip` or `*` with q > 0), "
    "decompressed while it is sent when it does not or is absent; `Vary: Accept-Encoding`. Such names are "
    "not listed.")


@router.get("/{job_id}/artifacts/{name}", operation_id="get_artifact", tags=["artifacts"],
            summary="Download one artifact", description=_GET_ARTIFACT_DESCRIPTION,
            response_class=Response,
            responses={200: {"description": "The file.",
                             "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
                                         "application/json": {"schema": {}},
                                         "application/gzip": {"schema": {"type": "string", "format": "binary"}},
                                         "image/png": {"schema": {"type": "string", "format": "binary"}},
                                         "text/plain": {"schema": {"type": "string"}}}},
                       **problem_responses(401, 403, 404, 409)})
def get_artifact(job_id: str, name: str, who: Caller, jobs: Jobs, request: Request):
    """One artifact as stored; ``X.json`` stored as ``X.json.gz`` (the moves since issue 20) is served
    as JSON: the gzip bytes with ``Content-Encoding: gzip`` when ``Accept-Encoding`` admits gzip, else
    decompressed on the fly (streamed in 64 KiB pieces, never whole in memory). A missing
    ``Accept-Encoding`` gets the plain JSON (clients that send none may not decode gzip)."""
    path = jobs.artifact_path(job_id, name, who)
    if path.name == name:
        return FileResponse(path, media_type=media_type(path.name), filename=path.name)
    vary = {"Vary": "Accept-Encoding"}
    if accepts_gzip(request.headers.get("accept-encoding")):
        return FileResponse(path, media_type=media_type(name), filename=name,
                            headers={**vary, "Content-Encoding": "gzip"})
    return StreamingResponse(iter_gunzipped(path), media_type=media_type(name),
                             headers={**vary, "Content-Disposition": f'attachment; filename="{name}"'})
