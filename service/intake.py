"""Turning a ``POST /jobs`` request into an accepted, validated submission on disk.

Two request forms:

- ``multipart/form-data``: the scan as file part ``cloud`` (a point cloud, a mesh or an image read as
  a relief); optional ``parameters`` (the plan configuration as JSON text), ``name``, ``format`` (one
  of ``planning.inputs.cloud.FORMATS``: ply, pcd, xyz, csv, txt, stl, obj, las, laz, e57, png, jpg,
  jpeg, bmp, tif, tiff), ``time_limit_s``, and ``fixtures`` (zero or more fixture point-cloud files).
- ``application/json``: :class:`schemas.api.JobCreateRequest`, a small inline cloud.

Uploads are copied into a fresh staging folder under ``DATA_DIR/tmp`` (with their SHA-256), the
parameters are validated by ``schemas.params.parse_config`` and the cloud is read once by
``planning.inputs.cloud.read_input`` in a child process under the job's memory limit
(:mod:`service.validation`), never in the API process, so a truncated file, garbage, NaN, an empty
cloud, an image bomb or a header claiming billions of points is answered with a 4xx problem naming
what is wrong while the service goes on answering everyone else. On any error the staging folder is
removed: nothing half-written stays behind.

Before anything is written the free space of the data directory is checked
(:func:`service.diskspace.check_free_space`, with the declared ``Content-Length``, then each part's
size); a write that still fails with ENOSPC is answered 507 ``insufficient_storage`` too. The
multipart parser's own limits (files, fields, text-field and part-header sizes) are answered with
problems that name the limit (``too_many_fixtures`` naming ``SCANMILL_MAX_FIXTURES``,
``too_many_fields``, ``field_too_large``, ``part_header_too_large``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
from collections.abc import Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
from pydantic import ValidationError
from starlette.datastructures import FormData, UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import Request

from planning.errors import ParameterError
from planning.inputs.cloud import FORMATS, SUPPORTED
from schemas.api import InlineCloud
from schemas.params import PlanConfig, parse_config
from service.diskspace import InsufficientStorage, check_free_space
from service.problems import ApiError, disk_full_error, is_disk_full
from service.settings import Settings
from service.storage import Storage, UploadTooLarge, cloud_suffix, copy_stream
from service.validation import SubmissionChecker, fixture_paths

MULTIPART_FIELDS = {"cloud", "parameters", "name", "format", "time_limit_s", "fixtures"}
# image parts are scans too: an image is read as a relief (input.relief)
_IMAGE_CLOUD_TYPES = {"image/png", "image/jpeg", "image/pjpeg", "image/bmp", "image/x-bmp", "image/x-ms-bmp",
                      "image/tiff"}
# media types that are certainly not a point cloud (a part sent with one of these is refused)
_NOT_A_CLOUD_PREFIXES = ("image/", "audio/", "video/", "font/", "multipart/")
_NOT_A_CLOUD = {"application/pdf", "application/zip", "application/gzip", "application/x-gzip",
                "application/x-tar", "application/x-7z-compressed", "application/x-rar-compressed",
                "application/msword", "application/vnd.ms-excel", "text/html", "application/json",
                "application/xml", "text/xml", "application/javascript"}
log = logging.getLogger("scanmill.service")
_IDEMPOTENCY_KEY_RE = re.compile(r"^[\x21-\x7e]{1,255}$")
#: the largest text field of a multipart POST /jobs (parameters, name, format, time_limit_s); fixed
MAX_TEXT_FIELD_BYTES = 1 << 20
#: the most text fields in a multipart POST /jobs (four are meaningful; a few more get a clear 422)
MAX_FORM_FIELDS = 16
try:                                   # the multipart parser's own limits on the header lines of a part
    from python_multipart.multipart import DEFAULT_MAX_HEADER_COUNT as PART_HEADER_COUNT
    from python_multipart.multipart import DEFAULT_MAX_HEADER_SIZE as PART_HEADER_BYTES
except ImportError:  # pragma: no cover - older python-multipart
    PART_HEADER_COUNT, PART_HEADER_BYTES = 8, 4096 + 128
FIXTURES_WARNING = ("fixture files are stored with the job but not used yet: collision checks against fixtures "
                    "come with global visibility (visibility.global), which this version does not have")


@dataclass
class Submission:
    """A validated job submission whose files sit in ``staging`` until the job is stored."""

    staging: Path
    config: PlanConfig
    input: dict[str, Any]                      # JobInput fields + internal path/fmt/fixture_paths
    time_limit_s: float
    warnings: list[str] = field(default_factory=list)
    request_hash: str = field(init=False)      # what an Idempotency-Key replay must match

    def __post_init__(self) -> None:
        self.request_hash = _request_hash(self.config, self.input, self.time_limit_s)


def _clean_name(name: str | None) -> str | None:
    if not name:
        return None
    base = os.path.basename(str(name).replace("\\", "/"))
    base = "".join(c for c in base if c.isprintable()).strip()
    return base[:200] or None


def _check_part_type(part: UploadFile, field_name: str) -> None:
    ct = (part.content_type or "").split(";")[0].strip().lower()
    if field_name == "cloud" and ct in _IMAGE_CLOUD_TYPES:
        return
    if ct.startswith(_NOT_A_CLOUD_PREFIXES) or ct in _NOT_A_CLOUD:
        raise ApiError(415, "unsupported_media_type",
                       f"The '{field_name}' part is sent as {ct}, which is not a point cloud. Send the scan file "
                       f"({SUPPORTED}) as application/octet-stream.")


def _parse_parameters(text: str | None) -> PlanConfig:
    if text is None or not text.strip():
        return check_service_parameters(parse_config({}))
    try:
        data = json.loads(text)
    except RecursionError:
        raise ApiError(422, "invalid_parameter", "The 'parameters' field nests too deeply to be a plan "
                                                 "configuration.") from None
    except json.JSONDecodeError as exc:
        raise ApiError(422, "invalid_parameter",
                       f"The 'parameters' field is not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno}); "
                       'send the plan configuration as a JSON object, e.g. {"setups": {"coverage": 0.95}}.') from None
    if not isinstance(data, dict):
        raise ApiError(422, "invalid_parameter", "The 'parameters' field must be a JSON object grouped by stage, "
                                                 'e.g. {"setups": {"coverage": 0.95}}.',
                       errors=["parameters: must be a JSON object"])
    return check_service_parameters(parse_config(data))


def check_service_parameters(config: PlanConfig) -> PlanConfig:
    """What the service allows beyond the schema: machine profiles by bundled name only and no mesh fixtures
    (a path would let a client make the service read files of its own choosing)."""
    from planning.orientations.kinematics import available_profiles
    names = list(available_profiles())
    if config.machine.profile not in names:
        raise ParameterError(f"machine.profile = {config.machine.profile[:80]!r}: the service accepts the bundled "
                             f"profiles only: {', '.join(names)}",
                             problems=[f"machine.profile: one of {', '.join(names)}"])
    meshes = [i for i, it in enumerate(config.fixtures.items) if it.type == "mesh"]
    if meshes:
        raise ParameterError(f"fixtures.items[{meshes[0]}]: mesh fixtures read a file path, which the service does not "
                             "accept; give the fixture as boxes, cylinders or points_mm, or use the CLI",
                             problems=[f"fixtures.items[{i}].type: 'mesh' is CLI only" for i in meshes])
    if config.stock.type == "mesh":
        raise ParameterError("stock.type = 'mesh' reads a file path, which the service does not accept; give the "
                             "blank as a box (stock.min_mm/max_mm) or a cylinder, or use the CLI",
                             problems=["stock.type: 'mesh' is CLI only"])
    return config


def _time_limit(value: Any, settings: Settings) -> float:
    if value is None or value == "":
        return settings.job_time_limit_s
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise ApiError(422, "invalid_request", f"time_limit_s = {str(value)[:40]!r} is not a number of seconds.",
                       errors=["time_limit_s: not a number"]) from None
    if not (t > 0):                 # also NaN
        raise ApiError(422, "invalid_request", f"time_limit_s = {t:g} must be a positive number of seconds.",
                       errors=["time_limit_s: must be > 0"])
    if t > settings.job_time_limit_s:
        raise ApiError(422, "invalid_request",
                       f"time_limit_s = {t:g} exceeds this service's limit of {settings.job_time_limit_s:g} s "
                       "(SCANMILL_JOB_TIME_LIMIT_S).", errors=["time_limit_s: above the service limit"],
                       limit="SCANMILL_JOB_TIME_LIMIT_S", limit_value=settings.job_time_limit_s)
    return t


def check_idempotency_key(key: str | None) -> str | None:
    """Validate an ``Idempotency-Key`` header value (1-255 visible ASCII characters)."""
    if key is None:
        return None
    if not _IDEMPOTENCY_KEY_RE.match(key):
        raise ApiError(422, "invalid_idempotency_key",
                       "The Idempotency-Key header must be 1 to 255 visible ASCII characters (e.g. a UUID).",
                       errors=["header Idempotency-Key: 1-255 visible ASCII characters"])
    return key


def _request_hash(config: PlanConfig, input_: dict[str, Any], time_limit_s: float | None) -> str:
    doc = {"parameters": config.to_json_dict(), "cloud": input_["sha256"], "fmt": input_.get("fmt"),
           "name": input_.get("name"), "fixtures": input_.get("fixture_sha256", []), "time_limit_s": time_limit_s}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def _disk_full(settings: Settings, needed: int, what: str) -> ApiError:
    """After a write failed with ENOSPC: the free-space check again (its 507 names the space needed and free),
    or, if the space is back already, the 507 for a disk that filled up meanwhile."""
    try:
        check_free_space(settings, needed, what)
    except InsufficientStorage as exc:
        return exc
    return disk_full_error(settings, what)


async def _copy_part(part: UploadFile, dst: Path, settings: Settings, what: str) -> tuple[int, str]:
    needed = int(part.size or 0)
    check_free_space(settings, needed, f"the {what} file")
    try:
        return await anyio.to_thread.run_sync(
            lambda: copy_stream(part.file, dst, max_bytes=settings.max_upload_bytes))
    except UploadTooLarge:
        raise ApiError(413, "file_too_large",
                       f"The {what} file is larger than {settings.max_upload_bytes:,} bytes, the limit of this "
                       f"service (SCANMILL_MAX_UPLOAD_BYTES = {settings.max_upload_bytes}). Decimate the scan or "
                       "save it as binary PLY.",
                       limit="SCANMILL_MAX_UPLOAD_BYTES", limit_value=settings.max_upload_bytes) from None
    except OSError as exc:                     # copy_stream removed the partial file
        if not is_disk_full(exc):
            raise
        raise _disk_full(settings, needed, f"the {what} file") from None


def _declared_length(request: Request) -> int:
    value = request.headers.get("content-length", "").strip()
    return int(value) if value.isdigit() else 0


def _too_many_fixtures(settings: Settings, sent: str) -> ApiError:
    n = settings.max_fixtures
    return ApiError(422, "too_many_fixtures",
                    f"{sent}; a job takes one cloud and at most {n} fixture files (SCANMILL_MAX_FIXTURES = {n}). "
                    f"Send at most {n} 'fixtures' parts (merge fixture clouds into one file if need be).",
                    errors=[f"fixtures: at most {n} files"], limit="SCANMILL_MAX_FIXTURES", limit_value=n)


def _field_too_large(name: str | None = None) -> ApiError:
    which = f"'{name}'" if name else "(parameters, name, format or time_limit_s)"
    return ApiError(413, "field_too_large",
                    f"A multipart text field {which} is larger than {MAX_TEXT_FIELD_BYTES:,} bytes (1 MiB), the limit "
                    "for a text field of POST /jobs (fixed; not a setting). Send only the plan configuration as "
                    "'parameters' (a few kB); the scan and fixture clouds go as files ('cloud', 'fixtures').",
                    errors=[f"{name or 'field'}: at most {MAX_TEXT_FIELD_BYTES} bytes"],
                    limit="multipart text field bytes", limit_value=MAX_TEXT_FIELD_BYTES)


def _multipart_problem(exc: StarletteHTTPException, settings: Settings) -> Exception:
    """The problem for a multipart body the parser refused: name the limit it hit, and what to do."""
    detail = str(exc.detail)
    causes, e = [], exc.__context__
    while e is not None and len(causes) < 5:
        causes.append(str(e))
        e = e.__cause__ or e.__context__
    why = " ".join(causes).lower()
    if "maximum number of files" in detail.lower():
        return _too_many_fixtures(settings, f"The upload has more files than one cloud and {settings.max_fixtures} "
                                            "fixtures")
    if "maximum number of fields" in detail.lower():
        return ApiError(422, "too_many_fields",
                        f"The multipart body has more than {MAX_FORM_FIELDS} text fields, the limit of POST /jobs. "
                        "Its text fields are parameters, name, format and time_limit_s, each sent once.",
                        errors=[f"fields: at most {MAX_FORM_FIELDS}"], limit="multipart text fields",
                        limit_value=MAX_FORM_FIELDS)
    if "exceeded maximum size" in detail.lower():
        return _field_too_large()
    if "maximum header size" in why:
        return ApiError(413, "part_header_too_large",
                        f"A header line of a multipart part is longer than {PART_HEADER_BYTES:,} bytes, the multipart "
                        "parser's limit; usually a file name of thousands of characters in Content-Disposition. "
                        "Give the file a shorter name (the service keeps 200 characters of it) and send it again.",
                        limit="multipart part header line bytes", limit_value=PART_HEADER_BYTES)
    if "maximum header count" in why:
        return ApiError(400, "bad_request",
                        f"A part of the multipart body has more than {PART_HEADER_COUNT} header lines, the multipart "
                        "parser's limit. Send each part with Content-Disposition and Content-Type only.",
                        limit="multipart part header lines", limit_value=PART_HEADER_COUNT)
    return exc                                 # other unreadable bodies: 400 bad_request, the parser's words


@asynccontextmanager
async def _read_form(request: Request, settings: Settings):
    """``request.form()`` with the service's limits; the parser's refusals become problems naming the limit."""
    try:
        form: FormData = await request.form(max_files=1 + settings.max_fixtures, max_fields=MAX_FORM_FIELDS,
                                            max_part_size=MAX_TEXT_FIELD_BYTES)
    except StarletteHTTPException as exc:
        if exc.status_code != 400:
            raise
        raise _multipart_problem(exc, settings) from None
    except OSError as exc:                     # the parser spools file parts to a temporary file
        if not is_disk_full(exc):
            raise
        raise _disk_full(settings, _declared_length(request), "the upload") from None
    try:
        yield form
    finally:
        await form.close()


async def receive_submission(request: Request, settings: Settings, storage: Storage,
                             limiter: anyio.CapacityLimiter) -> Submission:
    """Read a submission into a staging folder and check its fields; raise :class:`ApiError` / planning errors.

    The cloud itself is read by :func:`validate_submission` (after the idempotency check).
    The caller owns ``Submission.staging`` and removes it if the job is not stored.
    """
    ct = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ct == "multipart/form-data":
        return await _receive_multipart(request, settings, storage, limiter)
    if ct == "application/json":
        return await _receive_json(request, settings, storage, limiter)
    raise ApiError(415, "unsupported_media_type",
                   f"POST /jobs takes multipart/form-data (the scan as file part 'cloud') or application/json "
                   f"(a small inline cloud), not {ct or 'a body without Content-Type'}.")


async def _receive_multipart(request: Request, settings: Settings, storage: Storage,
                             limiter: anyio.CapacityLimiter) -> Submission:
    staging: Path | None = None
    try:
        # before anything is written (the parser spools file parts, then they are copied into staging)
        check_free_space(settings, _declared_length(request), "the upload")
        async with _read_form(request, settings) as form:
            unknown = sorted({k for k in form.keys() if k not in MULTIPART_FIELDS})
            if unknown:
                raise ApiError(422, "invalid_request",
                               f"Unknown multipart field(s): {', '.join(unknown)}; the fields are "
                               f"{', '.join(sorted(MULTIPART_FIELDS))}.",
                               errors=[f"{k}: unknown field" for k in unknown])
            for k in ("cloud", "parameters", "name", "format", "time_limit_s"):
                if len(form.getlist(k)) > 1:
                    raise ApiError(422, "invalid_request", f"The multipart field '{k}' is given more than once.",
                                   errors=[f"{k}: given more than once"])
            cloud = form.get("cloud")
            if cloud is None:
                raise ApiError(422, "missing_cloud", "The multipart body has no 'cloud' part: attach the scan "
                                                     "file as the file field 'cloud'.", errors=["cloud: required"])
            if not isinstance(cloud, UploadFile):
                raise ApiError(422, "invalid_request", "The 'cloud' part must be a file (with a filename), "
                                                       "not a text field.", errors=["cloud: must be a file"])
            texts: dict[str, str | None] = {}
            for k in ("parameters", "name", "format", "time_limit_s"):
                v = form.get(k)
                if isinstance(v, UploadFile):     # a text field sent as a file part: same limit
                    raw = await v.read(MAX_TEXT_FIELD_BYTES + 1)
                    if len(raw) > MAX_TEXT_FIELD_BYTES:
                        raise _field_too_large(k)
                    v = raw.decode("utf-8", errors="replace")
                texts[k] = v
            fixtures = form.getlist("fixtures")
            if len(fixtures) > settings.max_fixtures:
                raise _too_many_fixtures(settings, f"{len(fixtures)} fixture files were sent")
            if any(not isinstance(f, UploadFile) for f in fixtures):
                raise ApiError(422, "invalid_request", "Every 'fixtures' part must be a file.",
                               errors=["fixtures: must be files"])
            _check_part_type(cloud, "cloud")
            for f in fixtures:
                _check_part_type(f, "fixtures")

            config = _parse_parameters(texts["parameters"])
            fmt = (texts["format"] or "").strip().lower() or None
            if fmt is not None and fmt not in FORMATS:
                raise ApiError(422, "invalid_request", f"format = {fmt[:20]!r}; allowed: {', '.join(FORMATS)} "
                                                       "(or leave it out to detect it).",
                               errors=["format: not one of " + ", ".join(FORMATS)])
            time_limit = _time_limit(texts["time_limit_s"], settings)
            name = _clean_name(texts["name"]) or _clean_name(cloud.filename)

            staging = storage.new_staging()
            cloud_file = f"cloud{cloud_suffix(cloud.filename)}"
            size, sha = await _copy_part(cloud, staging / cloud_file, settings, "cloud")
            fixture_paths, fixture_names, fixture_sha = [], [], []
            for i, f in enumerate(fixtures):
                fname = f"fixture-{i}{cloud_suffix(f.filename)}"
                _, fsha = await _copy_part(f, staging / fname, settings, f"fixture {i}")
                fixture_paths.append(f"input/{fname}")
                fixture_names.append(_clean_name(f.filename) or fname)
                fixture_sha.append(fsha)
        input_ = {"name": name, "size_bytes": size, "sha256": sha, "fmt": fmt, "path": f"input/{cloud_file}",
                  "fixtures": fixture_names, "fixture_paths": fixture_paths, "fixture_sha256": fixture_sha}
        return Submission(staging=staging, config=config, input=input_, time_limit_s=time_limit,
                          warnings=[FIXTURES_WARNING] if fixtures else [])
    except BaseException:
        storage.discard(staging)
        raise


def _inline_to_ply(body: bytes, settings: Settings, staging: Path) -> tuple[PlanConfig, dict[str, Any], float | None]:
    """Parse and check an inline JSON submission and write its cloud as binary PLY (in a worker thread).

    Returns the configuration, the submission's ``input`` and the requested time limit (unchecked)."""
    import numpy as np

    from planning.report.files import write_ply
    try:
        doc = json.loads(body)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ApiError(422, "invalid_request", f"The JSON body cannot be parsed: {exc}.") from None
    except RecursionError:
        raise ApiError(422, "invalid_request", "The JSON body nests too deeply.") from None
    if not isinstance(doc, dict):
        raise ApiError(422, "invalid_request", "The JSON body must be an object with 'cloud' and 'parameters'.")
    unknown = sorted(set(doc) - {"cloud", "parameters", "name", "time_limit_s"})
    if unknown:
        raise ApiError(422, "invalid_request", f"Unknown field(s) in the JSON body: {', '.join(unknown)}.",
                       errors=[f"{k}: unknown field" for k in unknown])
    if "parameters" in doc and not isinstance(doc["parameters"], dict):
        raise ApiError(422, "invalid_parameter", "parameters must be a JSON object grouped by stage, e.g. "
                                                 '{"setups": {"coverage": 0.95}} (or left out for the defaults).',
                       errors=["parameters: must be an object"])
    config = check_service_parameters(parse_config(doc.get("parameters", {})))
    raw = doc.get("cloud")
    n = len(raw["points"]) if isinstance(raw, dict) and isinstance(raw.get("points"), list) else 0
    if n > settings.max_inline_points:
        raise ApiError(413, "too_many_points",
                       f"The inline cloud has {n:,} points; the limit for JSON requests is "
                       f"{settings.max_inline_points:,} (SCANMILL_MAX_INLINE_POINTS). Upload larger clouds as a "
                       "file (multipart/form-data, field 'cloud').", limit="SCANMILL_MAX_INLINE_POINTS",
                       limit_value=settings.max_inline_points)
    try:
        cloud = InlineCloud.model_validate(raw)
    except ValidationError as exc:
        errors = []
        for e in exc.errors()[:20]:
            loc = ".".join(str(p) for p in ("cloud", *e.get("loc", ())))
            errors.append(f"{loc}: {e.get('msg', 'invalid')}")
        raise ApiError(422, "invalid_request", "The inline cloud is not valid: " + "; ".join(errors),
                       errors=errors) from None
    name = doc.get("name")
    if name is not None and (not isinstance(name, str) or len(name) > 200):
        raise ApiError(422, "invalid_request", "name must be a string of at most 200 characters.",
                       errors=["name: string, at most 200 characters"])
    tl = doc.get("time_limit_s")
    if tl is not None and (isinstance(tl, bool) or not isinstance(tl, (int, float))):
        raise ApiError(422, "invalid_request", "time_limit_s must be a number of seconds (or null).",
                       errors=["time_limit_s: must be a number"])
    pts = np.asarray(cloud.points, dtype=np.float64).reshape(-1, 3)
    normals = None
    if cloud.normals is not None:
        normals = np.asarray(cloud.normals, dtype=np.float64).reshape(-1, 3)
        if normals.shape != pts.shape:
            raise ApiError(422, "invalid_request",
                           f"cloud.normals has {normals.shape[0]} rows but cloud.points has {pts.shape[0]}; "
                           "give one normal per point.", errors=["cloud.normals: one row per point"])
    write_ply(staging / "cloud.ply", pts, normals=normals, binary=True)
    data = (staging / "cloud.ply").read_bytes()
    input_ = {"name": _clean_name(name) or "inline", "size_bytes": len(data),
              "sha256": hashlib.sha256(data).hexdigest(), "fmt": "ply", "path": "input/cloud.ply",
              "fixtures": [], "fixture_paths": [], "fixture_sha256": []}
    return config, input_, tl


async def _receive_json(request: Request, settings: Settings, storage: Storage,
                        limiter: anyio.CapacityLimiter) -> Submission:
    check_free_space(settings, _declared_length(request), "the request")
    body = await request.body()
    staging: Path | None = None
    try:
        check_free_space(settings, len(body), "the inline cloud")    # its PLY is smaller than its JSON
        staging = storage.new_staging()
        try:
            config, input_, tl = await anyio.to_thread.run_sync(
                lambda: _inline_to_ply(body, settings, staging), limiter=limiter)
        except OSError as exc:
            if not is_disk_full(exc):
                raise
            raise _disk_full(settings, len(body), "the inline cloud") from None
        return Submission(staging=staging, config=config, input=input_, time_limit_s=_time_limit(tl, settings))
    except BaseException:
        storage.discard(staging)
        raise


def _name_the_upload(exc, stored: str, name: str | None) -> None:
    """A reader names the file it read ('cloud.stl', as stored); the client knows it by its own name."""
    if name and name != stored and repr(stored) in exc.message:
        exc.message = exc.message.replace(repr(stored), repr(name))
        exc.args = (exc.message,)


async def validate_submission(sub: Submission, checker: SubmissionChecker,
                              disconnected: Callable[[], Awaitable[bool]] | None = None) -> None:
    """Read the cloud and the fixtures once, in a child process (:mod:`service.validation`), and fill in what
    was read; 4xx problems on errors, :class:`service.validation.ClientGone` if the client left meanwhile."""
    from planning.errors import PlanningError

    path = sub.staging / Path(sub.input["path"]).name
    spec = {"path": str(path), "fmt": sub.input.get("fmt"), "parameters": sub.config.to_json_dict(),
            "fixtures": fixture_paths(sub.staging, sub.input)}
    try:
        info = await checker.check(spec, disconnected=disconnected)
    except PlanningError as exc:
        if not exc.message.startswith("fixture "):
            _name_the_upload(exc, path.name, sub.input.get("name"))
        raise
    sub.warnings.extend(info.pop("warnings", []))
    sub.input.update(info)
