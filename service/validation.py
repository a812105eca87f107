"""Checking a submission's files in a child process, never in the API process's own memory.

Reading a scan is where hostile input costs the most: an image of a few hundred bytes can claim
millions of pixels, a header can claim billions of records. The API process must stay small and its
event loop free whatever it is sent (``/healthz`` answers while any upload is checked), so
:class:`SubmissionChecker` runs :func:`check_files` (read the cloud as the worker will, check the
part's size, count the points a mesh will be planned on, estimate the job's memory; read each
fixture) in a process of its own:

* forked from the same ``forkserver`` as the job workers (the planning modules are imported there
  once, so a check starts in milliseconds; ``spawn`` where there is no fork server);
* under an address-space limit (:func:`service.memlimit.apply_job_memory_limit`) of
  ``SCANMILL_JOB_MEMORY_MB``, the budget the job itself will run under: a file that cannot be read
  within it is answered ``413 too_large_for_memory`` naming the setting, and the host never runs short;
* at most ``SCANMILL_VALIDATION_WORKERS`` at once, side by side; the others wait their turn without
  holding a thread;
* for at most ``SCANMILL_VALIDATION_TIME_LIMIT_S`` seconds (``422 validation_timeout`` past it);
* killed at once when the client that sent the request goes away (:class:`ClientGone`), so a client
  that gives up before its 202 leaves neither a job nor a process behind.

The child answers with a plain tuple: ``("ok", info)``, or the error as data (a planning error's
class, code, message and details; a service problem's status, code, detail and members), which
:func:`_raise` raises again in the API process as the same error: the client gets the same 4xx
problem document as when the check ran in-process.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio

from service.problems import ApiError
from service.settings import Settings

log = logging.getLogger("scanmill.service")

#: How often the API process looks whether the child answered or the client went away, seconds.
POLL_S = 0.05


class ClientGone(Exception):
    """The client closed its connection while its submission was being checked (the check was stopped)."""


def check_files(spec: dict[str, Any]) -> dict[str, Any]:
    """Read the submission's cloud and fixtures as the worker will; returns what was read.

    ``spec``: ``path`` and ``fmt`` of the stored cloud, ``parameters`` (the plan configuration as
    JSON), ``fixtures`` (paths), ``settings`` (:class:`~service.settings.Settings` as a dict). Returns
    ``format``, ``n_points``, ``has_normals``, ``extent_mm`` (and ``warnings``, what reading changed);
    raises planning errors and :class:`ApiError` (``job_too_large``).
    """
    from planning.errors import ParameterError, PlanningError
    from planning.inputs.cloud import read_cloud
    from planning.inputs.facet_points import planned_point_count
    from planning.inputs.scale import check_part_size
    from schemas.params import parse_config
    from service.admission import check_job_budget
    from service.workers import read_job_cloud

    settings = Settings.model_validate(spec["settings"])
    config = parse_config(spec["parameters"])
    cloud = read_job_cloud(spec["path"], spec.get("fmt"), config, settings.max_points)
    if config.normals.method == "input" and cloud.normals is None:
        raise ParameterError("normals.method is 'input' but the file carries no normals (PLY nx ny nz, PCD "
                             "normal_x normal_y normal_z); use normals.method = sphere_throwing",
                             code="missing_normals")
    check_part_size(cloud.points, units=config.input.units, tool_diameter_mm=config.tool.diameter_mm,
                    min_tool_diameters=config.input.min_part_tool_diameters,
                    max_extent_mm=config.input.max_extent_mm, accept_small_part=config.input.accept_small_part)
    extent = [float(v) for v in cloud.points.max(axis=0) - cloud.points.min(axis=0)]
    # a mesh is planned on points laid on its facets too (planning/inputs/facet_points.py)
    n_planned = planned_point_count(cloud.points, cloud.faces, config.input.mesh_sample_mm,
                                    config.input.mesh_max_points)
    check_job_budget(config, n_planned, settings, extent_mm=extent)
    info = {"format": cloud.source_format, "n_points": int(cloud.points.shape[0]),
            "has_normals": cloud.normals is not None, "extent_mm": extent,
            "warnings": list(getattr(cloud, "warnings", ()))}
    del cloud
    for i, fp in enumerate(spec.get("fixtures", [])):
        try:
            read_cloud(fp, max_points=settings.max_points, min_points=1)
        except PlanningError as exc:
            exc.message = f"fixture {i}: {exc.message}"
            exc.args = (exc.message,)
            raise
    return info


def _error_data(exc: BaseException, memory_mb: int) -> tuple[str, dict[str, Any]]:
    """An exception of the check as picklable data (see :func:`_raise`)."""
    from planning.errors import PlanningError
    from service.memlimit import is_memory_exhaustion

    if isinstance(exc, PlanningError) and _from_memory_exhaustion(exc):
        exc = MemoryError()              # a reader that ran out: say which limit it ran into on this service
    if isinstance(exc, PlanningError):
        return "planning", {"cls": type(exc).__name__, "code": exc.code, "status": int(exc.status),
                            "message": exc.message, "details": _plain(getattr(exc, "details", {}) or {})}
    if isinstance(exc, ApiError):
        return "api", {"status": exc.status, "code": exc.code, "detail": exc.detail, "title": exc.title,
                       "headers": dict(exc.headers), "extra": _plain(exc.extra)}
    if is_memory_exhaustion(exc):
        return "api", {"status": 413, "code": "too_large_for_memory", "title": None, "headers": {},
                       "detail": (f"Reading this file needs more memory than one job may use on this service "
                                  f"(SCANMILL_JOB_MEMORY_MB = {memory_mb:,} MiB). Decimate the scan or lower its "
                                  "resolution and submit it again."),
                       "extra": {"limit": "SCANMILL_JOB_MEMORY_MB", "limit_value": int(memory_mb)}}
    return "bug", {"type": type(exc).__name__, "text": str(exc)[:500]}


def _from_memory_exhaustion(exc: BaseException) -> bool:
    """Whether a planning error was raised for running out of memory (a reader's MemoryError, converted)."""
    from service.memlimit import is_memory_exhaustion

    if getattr(exc, "code", None) == "too_large_for_memory":
        return True
    seen, e = set(), exc.__cause__ or exc.__context__
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if is_memory_exhaustion(e):
            return True
        e = e.__cause__ or e.__context__
    return False


def _plain(value: Any) -> Any:
    """``value`` with numpy scalars and tuples made plain (picklable without numpy, JSON-able)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):
        try:
            return value.item()
        except (TypeError, ValueError):
            return str(value)
    return value


def _child(spec: dict[str, Any], conn) -> None:
    """The check's process: limit its memory, read, answer through ``conn``, exit."""
    from service.memlimit import apply_job_memory_limit
    from service.workers import _die_with_parent

    _die_with_parent(conn)
    memory_mb = int(spec["memory_mb"])
    try:
        apply_job_memory_limit(memory_mb)
        if spec["settings"].get("validation_start_delay_s"):
            time.sleep(float(spec["settings"]["validation_start_delay_s"]))
        answer: tuple[str, Any] = ("ok", check_files(spec))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back as data
        answer = _error_data(exc, memory_mb)
    try:
        conn.send(answer)
    except BaseException:  # noqa: BLE001 - the parent is gone, or the answer cannot be sent at all
        os._exit(71)
    conn.close()


def _raise(kind: str, data: dict[str, Any], what: str) -> None:
    """Raise again, in the API process, the error the child sent as data."""
    from planning import errors

    if kind == "planning":
        cls = getattr(errors, data["cls"], None)
        if not (isinstance(cls, type) and issubclass(cls, errors.PlanningError)):
            cls = errors.PlanningError
        exc = cls(data["message"], code=data["code"], **data["details"])
        exc.status = data["status"]
        raise exc
    if kind == "api":
        raise ApiError(data["status"], data["code"], data["detail"], title=data.get("title"),
                       headers=data.get("headers") or None, **data.get("extra", {}))
    log.error("checking the submitted %s failed unexpectedly: %s: %s", what, data.get("type"), data.get("text"))
    raise ApiError(422, "unreadable_file", f"The {what} file could not be read ({data.get('type')}); export it "
                                           "again as PLY, PCD, XYZ, STL, OBJ, LAS/LAZ, E57 or an image.")


class SubmissionChecker:
    """Runs :func:`check_files` in child processes, at most ``settings.validation_workers`` at once."""

    def __init__(self, settings: Settings):
        from service.workers import PRELOAD

        self.settings = settings
        self.limiter = anyio.CapacityLimiter(int(settings.validation_workers))
        method = settings.start_method
        if method == "forkserver" and "forkserver" not in multiprocessing.get_all_start_methods():
            method = "spawn"  # pragma: no cover - not on Linux
        self._ctx = multiprocessing.get_context(method)
        if method == "forkserver":
            self._ctx.set_forkserver_preload(PRELOAD)
        self.running = 0

    def warm(self, timeout_s: float = 60.0) -> bool:
        """Start the fork server now (it imports the planning modules once) rather than at the first upload;
        True once a process forked from it has run (at most ``timeout_s`` seconds waited)."""
        p = self._ctx.Process(target=_noop, daemon=True)
        p.start()
        p.join(timeout_s)
        return p.exitcode == 0

    async def check(self, spec: dict[str, Any], *, what: str = "cloud",
                    disconnected: Callable[[], Awaitable[bool]] | None = None) -> dict[str, Any]:
        """Run the check of ``spec`` in a child process and return its answer; raise its error.

        ``disconnected`` is awaited while the child works: once it says True, the child is killed and
        :class:`ClientGone` raised."""
        spec = {**spec, "settings": self.settings.model_dump(mode="json"),
                "memory_mb": int(self.settings.job_memory_limit_mb)}
        async with self.limiter:
            if disconnected is not None and await disconnected():
                raise ClientGone()
            parent, child = self._ctx.Pipe(duplex=False)
            proc = self._ctx.Process(target=_child, args=(spec, child), name="scanmill-check", daemon=True)
            await anyio.to_thread.run_sync(proc.start)
            child.close()
            self.running += 1
            try:
                answer = await self._wait(proc, parent, disconnected)
            finally:
                self.running -= 1
                parent.close()
                with anyio.CancelScope(shield=True):     # off the event loop, and even if the request is cancelled
                    await anyio.to_thread.run_sync(_reap, proc)
        kind, data = answer
        if kind == "ok":
            return data
        _raise(kind, data, what)
        raise AssertionError("unreachable")  # pragma: no cover

    async def _wait(self, proc, conn, disconnected) -> tuple[str, Any]:
        deadline = time.monotonic() + float(self.settings.validation_time_limit_s)
        limit = float(self.settings.validation_time_limit_s)
        while True:
            if conn.poll():
                try:
                    return conn.recv()
                except (EOFError, OSError):
                    break                      # the child died after all: its exit code says how
            if not proc.is_alive() and not conn.poll():
                break
            if disconnected is not None and await disconnected():
                raise ClientGone()
            if time.monotonic() > deadline:
                raise ApiError(422, "validation_timeout",
                               f"Reading and checking this file took longer than {limit:g} s, this service's limit "
                               "(SCANMILL_VALIDATION_TIME_LIMIT_S); nothing was kept. Decimate the scan or save "
                               "it as binary PLY and submit it again.",
                               limit="SCANMILL_VALIDATION_TIME_LIMIT_S", limit_value=limit)
            await anyio.sleep(POLL_S)
        code = proc.exitcode
        if code is not None and code < 0 and -code == signal.SIGKILL:
            # the kernel's OOM killer, or the host: the address-space limit turns ordinary overruns into
            # MemoryError, which the child answers; a kill means memory all the same
            return _error_data(MemoryError(), int(self.settings.job_memory_limit_mb))
        log.error("the submission check process ended without an answer (exit code %s)", code)
        raise ApiError(422, "unreadable_file", "The file could not be checked: its reader ended unexpectedly; "
                                               "export it again as PLY, PCD, XYZ, STL or OBJ.")


def _noop() -> None:
    """Started once so that the fork server is up (and has imported the planning code) early."""


def _reap(proc) -> None:
    """Kill the check's process if it still runs and wait for it (never leaves a zombie)."""
    if proc.is_alive():
        proc.kill()
    proc.join(5)


def fixture_paths(staging: Path, submission_input: dict[str, Any]) -> list[str]:
    """The staged fixture files of a submission, as paths the child can read."""
    return [str(staging / Path(fp).name) for fp in submission_input.get("fixture_paths", [])]
