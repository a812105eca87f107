"""Where numba keeps the compiled kernels, and which threading layer runs the parallel ones.

Imported first by ``planning/__init__.py``, so it runs before any module of ``planning`` defines an
``@njit(cache=True)`` function (numba picks a function's cache directory when the function is
decorated: :class:`numba.core.caching.UserProvidedCacheLocator` reads ``numba.config.CACHE_DIR`` then).
Only the standard library is imported here.

**Cache directory.** Without this, numba writes its cache files into ``__pycache__`` next to the
sources: inside the source tree, and nowhere at all for a read-only install (every process then
compiles again, a minute and more per plan). Unless the user set ``NUMBA_CACHE_DIR`` themselves, it
is set to the first of

1. ``$SCANMILL_CACHE_DIR``, if set;
2. ``${XDG_CACHE_HOME:-~/.cache}/scanmill/numba``;

that can be created and written, else to a private directory under the temporary directory
(``/tmp/scanmill-numba-UID``, mode 0700 and owned by this user: the cache files are pickles, so a
directory someone else could write into is never used; failing that, a fresh ``mkdtemp``). It is set
in ``os.environ`` so that worker processes (forkserver, spawn, Celery) inherit it, and also in
``numba.config`` if numba was imported already. ``scanmill warmup`` fills it (:mod:`planning.warmup`).
numba stamps each entry with a hash of its source file and the CPU, so a changed module or another
machine compiles again instead of loading stale code.

**Threading layer.** numba tries TBB first by default. The only TBB here is the old one Open3D
bundles (``open3d/libtbb.so.12``, interface 12050); once Open3D is imported, numba finds that
library loaded, refuses it (it needs 2021 update 6, 12060) and prints a ``NumbaWarning`` before
falling back to OpenMP. Installing a newer ``tbb`` wheel does not help: the ``libtbb.so.12`` Open3D
loaded first is the one numba's ``CDLL`` gets. So unless the user chose a layer
(``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY``), the priority is set to OpenMP,
then workqueue, then TBB: the layer that was in use anyway (GNU OpenMP, parallel over
``NUMBA_NUM_THREADS``), chosen without probing TBB, and still a working layer (workqueue) where
libgomp is missing. GNU OpenMP is not fork-safe; no process of the service runs a parallel kernel
and then forks (the fork server and the Celery main process only import).

**Idle OpenMP threads sleep.** Unless the user set ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT``, the wait
policy is set to ``PASSIVE``: a GNU OpenMP thread whose parallel kernel is done sleeps at once instead
of spinning for the next one (the default spins some 300,000 rounds first). The planner calls many
small parallel kernels between stretches of Python, and on the femur-like plan with two threads the
spinning took the core the Python thread, the finishing worker process or another job needed:
0.87-0.93x the CPU seconds and 0.93-1.00x the wall time with ``PASSIVE``, the same programs
(BENCHMARKS.md, "Idle OpenMP threads sleep"). libgomp reads the variable when it is loaded, at the first parallel kernel,
after ``planning`` is imported (tests/test_warmup.py checks what libgomp itself reports).
"""

from __future__ import annotations

import os
import stat
import sys
import tempfile
from pathlib import Path

#: Environment variable naming the directory of the compiled kernels (overrides the XDG default).
ENV_VAR = "SCANMILL_CACHE_DIR"
#: numba's layers in the order tried when the user chose none (see the module docstring).
THREADING_LAYER_PRIORITY = "omp workqueue tbb"
#: OpenMP's wait policy when the user chose none (see the module docstring).
OMP_WAIT_POLICY = "PASSIVE"

#: What :func:`configure` decided: ``cache_dir`` (str or None when the user's NUMBA_CACHE_DIR is kept
#: as it is), ``source`` (``NUMBA_CACHE_DIR``, ``SCANMILL_CACHE_DIR``, ``XDG``, ``temp``) and ``skipped``
#: (candidates that could not be written, with the reason).
state: dict = {"cache_dir": None, "source": None, "skipped": []}


def default_cache_dir() -> Path | None:
    """``$SCANMILL_CACHE_DIR``, else ``${XDG_CACHE_HOME:-~/.cache}/scanmill/numba`` (None without a home)."""
    explicit = os.environ.get(ENV_VAR, "").strip()
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "scanmill" / "numba"
    try:
        return Path.home() / ".cache" / "scanmill" / "numba"
    except (RuntimeError, KeyError):     # no HOME and no passwd entry
        return None


def _writable(path: Path) -> str | None:
    """None if ``path`` exists (created here if needed) and this process can write into it, else why not."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()      # the same test numba's locator makes
    except OSError as exc:
        return f"{type(exc).__name__}: {exc.strerror or exc}"
    return None


def _private_temp_dir() -> Path:
    """``$TMPDIR/scanmill-numba-UID`` if it is ours alone (0700, owned by us), else a fresh mkdtemp."""
    uid = os.getuid() if hasattr(os, "getuid") else None
    if uid is not None:
        path = Path(tempfile.gettempdir()) / f"scanmill-numba-{uid}"
        try:
            path.mkdir(mode=0o700, exist_ok=True)
            st = path.lstat()
            if stat.S_ISDIR(st.st_mode) and st.st_uid == uid and not st.st_mode & 0o077:
                return path
        except OSError:
            pass
    return Path(tempfile.mkdtemp(prefix="scanmill-numba-"))


def configure() -> dict:
    """Set ``NUMBA_CACHE_DIR``, the threading-layer priority and OpenMP's wait policy unless the user set
    them; return :data:`state`.

    Idempotent; called once when ``planning`` is imported.
    """
    if not os.environ.get("NUMBA_THREADING_LAYER") and not os.environ.get("NUMBA_THREADING_LAYER_PRIORITY"):
        os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = THREADING_LAYER_PRIORITY
    if not os.environ.get("OMP_WAIT_POLICY") and not os.environ.get("GOMP_SPINCOUNT"):
        os.environ["OMP_WAIT_POLICY"] = OMP_WAIT_POLICY
    if os.environ.get("NUMBA_CACHE_DIR"):
        state.update(cache_dir=os.environ["NUMBA_CACHE_DIR"],
                     source=state["source"] or "NUMBA_CACHE_DIR")
    else:
        skipped = []
        chosen, source = None, None
        candidate = default_cache_dir()
        if candidate is not None:
            why = _writable(candidate)
            if why is None:
                chosen, source = candidate, (ENV_VAR if os.environ.get(ENV_VAR, "").strip() else "XDG")
            else:
                skipped.append(f"{candidate} ({why})")
        if chosen is None:
            chosen, source = _private_temp_dir(), "temp"
        os.environ["NUMBA_CACHE_DIR"] = str(chosen)
        state.update(cache_dir=str(chosen), source=source, skipped=skipped)
    if "numba" in sys.modules:   # imported before planning: make its config read the variables now
        from numba.core import config as numba_config
        numba_config.reload_config()
    return state


configure()
