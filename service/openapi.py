"""The OpenAPI document: request bodies FastAPI cannot infer, problem responses, examples.

``POST /jobs`` reads its body itself (multipart or JSON), so its request body is declared here.
Every error response is declared as ``application/problem+json`` with :class:`schemas.api.Problem`;
FastAPI's default ``HTTPValidationError`` is replaced by it.
"""

from __future__ import annotations

import json
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic.json_schema import models_json_schema

from schemas.api import JobCreateRequest, Problem
from service.intake import FORMATS

PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}

_DESCRIPTIONS = {
    400: "Malformed request (e.g. unreadable multipart body).",
    401: "Missing or invalid API key.",
    403: "Anonymous request from outside the local machine (no API keys configured).",
    404: "No such job for this API key, or no such artifact.",
    408: "The request body stopped arriving for SCANMILL_BODY_READ_TIMEOUT_S (code body_timeout); the connection "
         "is closed.",
    409: "The job is not in a state that allows this (e.g. results of a job that has not succeeded).",
    413: "The upload, a part of it, or the cloud exceeds a limit of the service; the problem names it. A declared "
         "Content-Length over the limit is answered before the body is read, and the connection is closed.",
    415: "Unsupported content type.",
    422: "Invalid parameters, cloud or request; the problem names each. On POST /jobs also job_too_large: the "
         "job's memory estimate exceeds SCANMILL_JOB_MEMORY_MB (members limit, limit_value, estimate_mb, "
         "parameter).",
    429: "This API key already has SCANMILL_MAX_QUEUED_JOBS_PER_KEY jobs queued or running (code too_many_jobs); "
         "retry after Retry-After seconds, or cancel some.",
    507: "Not enough free disk space for the upload (code insufficient_storage): the problem names the space "
         "needed, the space free and SCANMILL_MIN_FREE_DISK_MB. Nothing was kept. Or (code storage_quota_exceeded) "
         "this API key's uploads and artifacts would pass SCANMILL_MAX_STORED_BYTES_PER_KEY: the problem names the "
         "limit, used_bytes and needed_bytes; delete finished jobs to free space.",
}

EXAMPLE_JOB_ID = "3f2b0c3e9a1d4b7c8e6f5a4b3c2d1e0f"

EXAMPLE_PARAMETERS = {
    "normals": {"method": "input"},
    "tool": {"diameter_mm": 10},
    "visibility": {"cone_deg": [10, 80]},
    "setups": {"coverage": 0.95, "max_setups": 2},
}

EXAMPLE_JOB = {
    "id": EXAMPLE_JOB_ID, "status": "running", "stage": "visibility", "progress": 0.52,
    "message": "start", "created_at": "2026-11-23T09:30:00.120+00:00", "started_at": "2026-11-23T09:30:00.310+00:00",
    "finished_at": None, "updated_at": "2026-11-23T09:30:01.020+00:00", "attempts": 1, "time_limit_s": 3600.0,
    "input": {"name": "half_sphere.ply", "format": "ply-binary_little_endian", "size_bytes": 152365,
              "n_points": 2537, "has_normals": True,
              "sha256": "9c1185a5c5e9fc54612808977ee8f548b2258d31c9b1b2b8f0f0e4a2d3c4b5a6", "fixtures": []},
    "parameters": EXAMPLE_PARAMETERS, "error": None, "result": None, "warnings": [],
    "links": {"self": f"/jobs/{EXAMPLE_JOB_ID}", "result": None, "artifacts": None},
}

EXAMPLE_PROBLEM = {
    "type": "https://scanmill.dev/problems/too-many-points", "title": "Content too large", "status": 413,
    "detail": "The cloud has 3,000,000,000 points; the limit is 20,000,000. Decimate the scan (e.g. a voxel grid "
              "of 0.2-0.5 mm) and submit it again.",
    "instance": "/jobs", "code": "too_many_points", "limit": "input.max_points / SCANMILL_MAX_POINTS",
    "limit_value": 20000000,
}

JOB_CREATE_FORM = {
    "title": "JobCreateForm",
    "type": "object",
    "description": "POST /jobs as multipart/form-data: the scan file and the plan configuration.",
    "required": ["cloud"],
    "properties": {
        "cloud": {"type": "string", "format": "binary",
                  "description": "The scan, in input.units: a point cloud (PLY ascii/binary, PCD, XYZ/CSV/TXT, "
                                 "LAS/LAZ, E57), a mesh (STL, OBJ, PLY with faces) or a PNG/JPEG/BMP/TIFF image "
                                 "read as a relief (input.relief, sizes in mm)."},
        "parameters": {"type": "string",
                       "description": "The plan configuration (docs/design.md parameter names) as JSON text; omitted "
                                      "groups take their defaults. See the PlanConfig schema.",
                       "examples": ['{"normals": {"method": "input"}, "setups": {"max_setups": 2}}']},
        "name": {"type": "string", "maxLength": 200, "description": "A name for the cloud (default: its file name)."},
        "format": {"type": "string", "enum": list(FORMATS),
                   "description": "The file format; detected when left out."},
        "time_limit_s": {"type": "number", "exclusiveMinimum": 0,
                         "description": "Wall-clock limit of the job in seconds, at most the service's limit."},
        "fixtures": {"type": "array", "items": {"type": "string", "format": "binary"},
                     "description": "Fixture point clouds (stored with the job; used once collision checks exist)."},
    },
}


def problem_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` entries declaring problem documents for these status codes."""
    out: dict[int | str, dict[str, Any]] = {}
    for c in codes:
        entry: dict[str, Any] = {"description": _DESCRIPTIONS.get(c, "Error."),
                                 "content": {"application/problem+json": {"schema": PROBLEM_REF}}}
        if c == 413:
            entry["content"]["application/problem+json"]["example"] = EXAMPLE_PROBLEM
        if c == 429:
            entry["headers"] = {"Retry-After": {"schema": {"type": "integer"},
                                                "description": "Seconds to wait before submitting again."}}
        if c == 401:
            entry["headers"] = {"WWW-Authenticate": {"schema": {"type": "string"},
                                                     "description": "Bearer challenge."}}
        out[c] = entry
    return out


CREATE_JOB_REQUEST_BODY = {
    "required": True,
    "description": "The scan and its plan configuration, as a multipart upload or (small clouds) inline JSON.",
    "content": {
        "multipart/form-data": {
            "schema": {"$ref": "#/components/schemas/JobCreateForm"},
            "encoding": {"cloud": {"contentType": "application/octet-stream"},
                         "fixtures": {"contentType": "application/octet-stream"}},
        },
        "application/json": {
            "schema": {"$ref": "#/components/schemas/JobCreateRequest"},
            "examples": {
                "tetrahedron-ish": {
                    "summary": "An inline cloud (a real one needs far more points)",
                    "value": {"name": "corner", "parameters": {"setups": {"max_setups": 3}},
                              "cloud": {"points": [[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], [5, 5, 1],
                                                   [1, 5, 5], [5, 1, 5], [3, 3, 3], [7, 2, 1], [2, 7, 1]]}},
                },
            },
        },
    },
}


JOB_LINKS = {
    "GetJob": {"operationId": "get_job", "parameters": {"job_id": "$response.body#/id"},
               "description": "Follow the job (poll until status is succeeded, failed or cancelled)."},
    "GetJobResult": {"operationId": "get_job_result", "parameters": {"job_id": "$response.body#/id"},
                     "description": "The plan, once the job has succeeded."},
    "ListArtifacts": {"operationId": "list_artifacts", "parameters": {"job_id": "$response.body#/id"},
                      "description": "The files, once the job has succeeded."},
    "DeleteJob": {"operationId": "delete_job", "parameters": {"job_id": "$response.body#/id"},
                  "description": "Cancel the job, or delete it once finished."},
}


def build_openapi(app: FastAPI) -> dict[str, Any]:
    """The service's OpenAPI document (cached on the app); limits shown are this service's settings."""
    if app.openapi_schema:
        return app.openapi_schema
    doc = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes,
                      tags=app.openapi_tags, separate_input_output_schemas=False)
    schemas = doc.setdefault("components", {}).setdefault("schemas", {})
    _, defs = models_json_schema([(JobCreateRequest, "validation"), (Problem, "validation")],
                                 ref_template="#/components/schemas/{model}")
    for name, schema in defs.get("$defs", {}).items():
        schemas.setdefault(name, schema)
    form = json.loads(json.dumps(JOB_CREATE_FORM))
    settings = getattr(app.state, "settings", None)
    if settings is not None:
        form["properties"]["fixtures"]["maxItems"] = settings.max_fixtures
        form["properties"]["time_limit_s"]["maximum"] = settings.job_time_limit_s
        inline = schemas.get("InlineCloud", {}).get("properties", {})
        for key in ("points", "normals"):
            target = inline.get(key, {})
            target = next((t for t in target.get("anyOf", []) if t.get("type") == "array"), target)
            if target.get("type") == "array":
                target["maxItems"] = settings.max_inline_points
    schemas["JobCreateForm"] = form
    create = doc.get("paths", {}).get("/jobs", {}).get("post")
    if create is not None:
        create["responses"]["202"]["links"] = JOB_LINKS
    for name in ("HTTPValidationError", "ValidationError"):
        schemas.pop(name, None)
    for path_item in doc.get("paths", {}).values():
        for op in path_item.values():
            if not isinstance(op, dict) or "responses" not in op:
                continue
            resp = op["responses"]
            if op.get("operationId") != "get_version":          # every store-backed operation may answer 503
                resp.setdefault("503", {"description": "The job store does not answer (retry after Retry-After "
                                                       "seconds); nothing was changed.",
                                        "content": {"application/problem+json": {"schema": PROBLEM_REF}}})
            r422 = resp.get("422")
            if r422 is not None:
                content = r422.get("content", {})
                if "application/json" in content and "application/problem+json" not in content:
                    resp["422"] = problem_responses(422)[422]
                elif "application/json" in content:
                    content.pop("application/json")
    app.openapi_schema = doc
    return doc
