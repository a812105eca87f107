"""Files of the service under ``SCANMILL_DATA_DIR``: uploads, artifacts, atomic writes, safe names.

The storage interface is :class:`Storage`: the API stages uploads and serves artifacts through it,
workers read inputs and publish artifacts through it; both address a job's files only by job id,
attempt and artifact name (the job store keeps paths relative to the job's folder). Two forms
(``SCANMILL_STORAGE``):

* ``local`` (:class:`Storage`, the embedded default): one server owns the directory, takes a lock
  on it, and at start sweeps everything no job owns.
* ``shared`` (:class:`SharedStorage`, the Celery default): a directory that every API and worker
  machine mounts (NFS, CephFS, SMB, or an S3 bucket through a POSIX mount that supports rename,
  such as s3fs or JuiceFS). No lock; each host stages uploads in its own ``tmp/HOST/``; the start
  sweep removes only this host's staging and job folders that no job has owned for an hour.

Layout::

    DATA_DIR/scanmill.sqlite3        the job store when SCANMILL_DATABASE_URL is unset (service/store.py)
    DATA_DIR/server.lock             held by the one server using this directory (local form)
    DATA_DIR/tmp/                    uploads being received (emptied at start; tmp/HOST/ in the shared form)
    DATA_DIR/jobs/ID/input/          the accepted cloud (cloud.EXT) and fixtures (fixture-N.EXT)
    DATA_DIR/jobs/ID/work-N/         attempt N writing its artifacts (removed when it ends)
    DATA_DIR/jobs/ID/result/         the artifacts of the succeeded job (renamed from work-N)

A job's files appear all at once: uploads are written into a staging folder under ``tmp/`` and
renamed into ``jobs/ID`` when accepted; artifacts are written into ``work-N`` and the folder is
renamed to ``result`` when the worker reports success. Artifact names are checked against a strict
pattern and resolved inside ``result/`` (no ``..``, no separators, no hidden files, no links), so a
request cannot reach a file outside the job's folder.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import shutil
import socket
import stat
import time
import uuid
from pathlib import Path
from typing import BinaryIO, Iterable

from planning.inputs.cloud import EXTENSIONS
from planning.report.files import atomic_path

JOB_ID_RE = re.compile(r"^[0-9a-f]{32}$")
ARTIFACT_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
#: File name extensions kept from an uploaded file's name (they drive format detection): every extension
#: the readers know (clouds, meshes, LAS/LAZ, E57, images).
CLOUD_SUFFIXES = EXTENSIONS

MEDIA_TYPES = {
    ".json": "application/json", ".png": "image/png", ".npz": "application/octet-stream",
    ".ply": "application/octet-stream", ".nc": "text/plain", ".ngc": "text/plain", ".gcode": "text/plain",
    ".tap": "text/plain", ".txt": "text/plain", ".csv": "text/plain", ".gz": "application/gzip",
}
#: Artifact names also served from their gzip form: ``X.json`` asked for, ``X.json.gz`` stored (the moves
#: of each area, ``area_<i>.moves.json.gz`` since issue 20; clients of older plans ask for ``.moves.json``).
GZIP_ALIAS_SUFFIXES = (".json",)


class StorageLocked(RuntimeError):
    """Another server process already uses this data directory."""


def new_job_id() -> str:
    """A fresh unguessable job id: 32 lowercase hex digits."""
    return uuid.uuid4().hex


def is_job_id(value: str) -> bool:
    """Whether ``value`` has the form of a job id (anything else is simply not found)."""
    return bool(JOB_ID_RE.match(value or ""))


def safe_artifact_name(name: str) -> bool:
    """Whether ``name`` is a plain file name an artifact may have (no path, not hidden, not a temp file)."""
    return bool(ARTIFACT_NAME_RE.match(name or "")) and ".." not in name and not name.endswith(".tmp")


def cloud_suffix(filename: str | None) -> str:
    """The known point-cloud extension of an uploaded file name, or '' (then the content decides)."""
    suffix = Path(filename or "").suffix.lower()
    return suffix if suffix in CLOUD_SUFFIXES else ""


def media_type(name: str) -> str:
    """The media type an artifact is served with."""
    return MEDIA_TYPES.get(Path(name).suffix.lower(), "application/octet-stream")


def gzip_alias(name: str) -> str | None:
    """The stored gzip file name that serves artifact ``name`` when no file has that name (``X.json`` ->
    ``X.json.gz``), or None for names without one."""
    return name + ".gz" if name.endswith(GZIP_ALIAS_SUFFIXES) else None


def accepts_gzip(accept_encoding: str | None) -> bool:
    """Whether an ``Accept-Encoding`` header value admits ``gzip`` (RFC 9110 12.5.3): ``gzip`` or
    ``x-gzip`` listed with a q-value above 0, or else ``*`` with one. A missing or empty header admits
    only the identity here (a client that sends none may well not decode gzip)."""
    best: dict[str, float] = {}
    for item in (accept_encoding or "").split(","):
        token, *params = [part.strip() for part in item.split(";")]
        if not token:
            continue
        q = 1.0
        for param in params:
            key, _, value = param.partition("=")
            if key.strip().lower() == "q":
                try:
                    q = float(value.strip())
                except ValueError:
                    q = 0.0
                if not 0.0 <= q <= 1.0:        # NaN included
                    q = 0.0
        best[token.lower()] = max(q, best.get(token.lower(), 0.0))
    for token in ("gzip", "x-gzip"):
        if token in best:
            return best[token] > 0.0
    return best.get("*", 0.0) > 0.0


def iter_gunzipped(path: Path, chunk: int = 1 << 16):
    """The decompressed bytes of the gzip file ``path``, piece by piece (about ``chunk`` bytes of
    output at a time; the file is read as it goes, never whole); the file is closed at the end or
    when the generator is closed."""
    import gzip

    with open(path, "rb") as fh, gzip.GzipFile(fileobj=fh, mode="rb") as gz:
        while True:
            piece = gz.read(chunk)
            if not piece:
                return
            yield piece


def fsync_dir(path: Path) -> None:
    """Flush a directory entry (after a rename) to disk; a no-op where directories cannot be opened."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder, fsync and rename."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    fsync_dir(path.parent)


def tree_bytes(path: str | os.PathLike) -> int:
    """Bytes of the regular files under ``path`` (links are not followed; what vanishes meanwhile counts 0)."""
    total = 0
    for folder, dirs, files in os.walk(path):
        for name in files:
            with contextlib.suppress(OSError):
                st = os.lstat(os.path.join(folder, name))
                if stat.S_ISREG(st.st_mode):
                    total += st.st_size
    return total


class UploadTooLarge(Exception):
    """A file part grew past its limit while being copied."""


def copy_stream(src: BinaryIO, dst_path: Path, *, max_bytes: int, chunk: int = 1 << 20) -> tuple[int, str]:
    """Copy ``src`` into a new file ``dst_path`` (fsynced); return (size, sha256 hex).

    Raises :class:`UploadTooLarge` past ``max_bytes`` (the partial file is removed).
    """
    h = hashlib.sha256()
    size = 0
    try:
        with open(dst_path, "xb") as out:
            while True:
                block = src.read(chunk)
                if not block:
                    break
                size += len(block)
                if size > max_bytes:
                    raise UploadTooLarge(size)
                h.update(block)
                out.write(block)
            out.flush()
            os.fsync(out.fileno())
    except BaseException:
        with contextlib.suppress(OSError):
            dst_path.unlink()
        raise
    return size, h.hexdigest()


class Storage:
    """The service's data directory, owned by one server (local form): paths, staging, atomic moves, cleanup."""

    kind = "local"

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root).resolve()
        self.jobs_dir = self.root / "jobs"
        self.tmp_dir = self.root / "tmp"
        self.db_path = self.root / "scanmill.sqlite3"
        self._lock_fd: int | None = None

    # -- lifecycle ---------------------------------------------------------------------------
    def open(self) -> None:
        """Create the folders and take the directory lock (one server per data directory)."""
        for d in (self.root, self.jobs_dir, self.tmp_dir):
            d.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.root / "server.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise StorageLocked(f"another scanmill server is using the data directory {self.root}") from None
            raise
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd

    def close(self) -> None:
        """Release the directory lock."""
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
                os.close(self._lock_fd)
            self._lock_fd = None

    # -- paths -------------------------------------------------------------------------------
    def job_dir(self, job_id: str) -> Path:
        """``jobs/ID`` (``job_id`` must be a job id)."""
        if not is_job_id(job_id):
            raise ValueError(f"not a job id: {job_id!r}")
        return self.jobs_dir / job_id

    def input_dir(self, job_id: str) -> Path:
        return self.job_dir(job_id) / "input"

    def work_dir(self, job_id: str, attempt: int) -> Path:
        return self.job_dir(job_id) / f"work-{int(attempt)}"

    def result_dir(self, job_id: str) -> Path:
        return self.job_dir(job_id) / "result"

    # -- uploads -----------------------------------------------------------------------------
    def new_staging(self) -> Path:
        """A fresh folder under ``tmp/`` for one request's uploads."""
        path = self.tmp_dir / f"upload-{uuid.uuid4().hex}"
        path.mkdir()
        return path

    def discard(self, path: Path | None) -> None:
        """Remove a staging or job folder, ignoring what is already gone."""
        if path is not None:
            shutil.rmtree(path, ignore_errors=True)

    def accept_staging(self, staging: Path, job_id: str) -> Path:
        """Move a staging folder to ``jobs/ID/input`` in one rename; return that folder."""
        job = self.job_dir(job_id)
        job.mkdir()
        target = self.input_dir(job_id)
        os.replace(staging, target)
        fsync_dir(job)
        fsync_dir(self.jobs_dir)
        return target

    # -- results -----------------------------------------------------------------------------
    def publish_result(self, job_id: str, attempt: int) -> Path:
        """Rename ``work-N`` to ``result`` (the artifacts appear together)."""
        work, result = self.work_dir(job_id, attempt), self.result_dir(job_id)
        if result.exists():
            shutil.rmtree(result)
        os.replace(work, result)
        fsync_dir(self.job_dir(job_id))
        return result

    def artifacts(self, job_id: str) -> list[Path]:
        """The artifact files of a job's result, sorted by name."""
        result = self.result_dir(job_id)
        if not result.is_dir():
            return []
        return sorted(p for p in result.iterdir()
                      if safe_artifact_name(p.name) and p.is_file() and not p.is_symlink())

    def artifact_path(self, job_id: str, name: str) -> Path | None:
        """The path of artifact ``name``, or None if there is no such artifact (or the name is unsafe)."""
        if not safe_artifact_name(name):
            return None
        result = self.result_dir(job_id).resolve()
        path = (result / name)
        try:
            resolved = path.resolve(strict=True)
        except (OSError, RuntimeError):
            return None
        if resolved.parent != result or path.is_symlink() or not resolved.is_file():
            return None
        return resolved

    def job_bytes(self, job_id: str) -> int:
        """Bytes of all files of a job (upload, artifacts, attempts in progress): what it keeps stored."""
        return tree_bytes(self.job_dir(job_id))

    def remove_job(self, job_id: str) -> None:
        """Delete all files of a job."""
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)

    def remove_work(self, job_id: str, attempt: int) -> None:
        shutil.rmtree(self.work_dir(job_id, attempt), ignore_errors=True)

    # -- cleanup at start ----------------------------------------------------------------------
    def sweep(self, known_jobs: Iterable[str]) -> list[str]:
        """Remove what no job owns: ``tmp/*``, job folders without a job, ``work-*`` of stopped attempts.

        Called at start, before any worker runs. Returns the removed paths (for the log).
        """
        known = set(known_jobs)
        removed: list[str] = []
        for p in self.tmp_dir.iterdir():
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
            removed.append(str(p))
        for p in self.jobs_dir.iterdir():
            if p.name not in known:
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
                removed.append(str(p))
                continue
            for w in p.glob("work-*"):
                shutil.rmtree(w, ignore_errors=True)
                removed.append(str(w))
        return removed


class SharedStorage(Storage):
    """A data directory mounted by several API and worker machines (shared form).

    No directory lock; uploads are staged in ``tmp/HOST/`` so that one host's start sweep never
    touches another host's uploads in flight; job folders without a job are removed only once they
    are older than ``orphan_age_s`` (a job's folder exists a moment before its row is committed).
    """

    kind = "shared"

    def __init__(self, root: str | os.PathLike, *, host: str | None = None, orphan_age_s: float = 3600.0):
        super().__init__(root)
        self.host = re.sub(r"[^A-Za-z0-9_.-]", "_", host or socket.gethostname())[:64] or "host"
        self.tmp_dir = self.root / "tmp" / self.host
        self.orphan_age_s = float(orphan_age_s)

    def open(self) -> None:
        """Create the folders (no lock: other machines use the directory at the same time)."""
        for d in (self.root, self.jobs_dir, self.tmp_dir):
            d.mkdir(parents=True, exist_ok=True)

    def close(self) -> None:
        pass

    def sweep(self, known_jobs: Iterable[str]) -> list[str]:
        """Remove this host's staged uploads and job folders no job has owned for ``orphan_age_s``."""
        known = set(known_jobs)
        removed: list[str] = []
        for p in self.tmp_dir.iterdir():
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
            removed.append(str(p))
        horizon = time.time() - self.orphan_age_s
        for p in self.jobs_dir.iterdir():
            try:
                old = p.stat().st_mtime < horizon
            except OSError:
                continue
            if p.name not in known and old:
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
                removed.append(str(p))
        return removed


def open_storage(data_dir: str | os.PathLike, kind: str = "local") -> Storage:
    """The storage of ``kind`` ('local' or 'shared') over ``data_dir``, not yet opened."""
    if kind == "shared":
        return SharedStorage(data_dir)
    if kind == "local":
        return Storage(data_dir)
    raise ValueError(f"unknown storage kind {kind!r} (local or shared)")
