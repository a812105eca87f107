"""``GET /jobs/{id}/viewer``: the plan viewer page of a job, and ``/viewer/static``: its scripts.

The page is the same for every caller and holds no job data, so it is served without a key (a
browser cannot send an ``Authorization`` header when it follows a link). It then fetches the job's
``viewer.*`` artifacts through ``GET /jobs/{id}/artifacts/{name}`` with the key as a Bearer header,
exactly as any client does: without the right key it gets 401 or 404 and shows the key form or the
refusal, never the plan. Not in the OpenAPI document: it is a page for people, not an operation for
clients (docs/viewer.md).
"""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import HTMLResponse

from scanmill.viewer import VendorMissing, check_vendor, page_html
from service.problems import ApiError
from service.storage import is_job_id

router = APIRouter()
STATIC_PREFIX = "/viewer/static/"


@router.get("/jobs/{job_id}/viewer", include_in_schema=False, response_class=HTMLResponse)
def job_viewer(job_id: str) -> HTMLResponse:
    if not is_job_id(job_id):
        raise ApiError(404, "job_not_found", f"No job {job_id[:100]!r}.")
    try:
        check_vendor()
    except VendorMissing as exc:
        raise ApiError(503, "viewer_not_installed", str(exc)) from None
    text, headers = page_html(artifacts_base=f"/jobs/{job_id}/artifacts/", static_base=STATIC_PREFIX,
                              title=f"scanmill job {job_id}")
    return HTMLResponse(text, headers=headers)
