"""``scanmill view PLAN_DIR``: the viewer page for a plan on disk, served on 127.0.0.1.

The same page as the service's ``GET /jobs/{id}/viewer``. Only the plan's viewer files, ``plan.json``
and its pictures are served, and only as regular files of the plan folder itself (no symbolic link,
nothing that resolves outside it: :func:`plan_file`). They are served only with a random key made at start (``Authorization: Bearer``), which the printed address hands to the page in
its fragment (``#key=...``, never sent to a server, so never in a log); other users of the machine
who find the port get 401.
"""

from __future__ import annotations

import hmac
import secrets
import socket
import sys
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

from scanmill.viewer import STATIC_DIR, page_html
from service.problems import problem_response

#: Files of a plan directory the page may fetch (its data, the plan and the pictures).
SERVED = ("viewer.json", "viewer.points.bin", "viewer.paths.bin", "plan.json", "preview.png", "deviation.png",
          "unmachined.png")


def create_local_app(plan_dir: Path, key: str) -> FastAPI:
    """The app serving ``plan_dir``'s viewer with ``key`` as its only accepted Bearer key."""
    app = FastAPI(title="scanmill view", docs_url=None, redoc_url=None, openapi_url=None)
    title = f"scanmill plan {plan_dir.name}"

    @app.get("/", response_class=HTMLResponse)
    def page() -> HTMLResponse:
        text, headers = page_html(artifacts_base="/artifacts/", static_base="/static/", title=title)
        return HTMLResponse(text, headers=headers)

    @app.get("/artifacts/{name}")
    def artifact(name: str, request: Request):
        given = request.headers.get("authorization", "")
        if not given.lower().startswith("bearer ") or not hmac.compare_digest(given[7:].strip().encode(), key.encode()):
            return problem_response(401, "unauthenticated", "Open the address `scanmill view` printed: it carries "
                                    "the key.", headers={"WWW-Authenticate": 'Bearer realm="scanmill view"'})
        path = plan_file(plan_dir, name) if name in SERVED else None
        if path is None:
            return problem_response(404, "artifact_not_found", f"The plan has no {name[:100]!r}.")
        return FileResponse(path, headers={"Cache-Control": "no-store"})

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app


def plan_file(plan_dir: Path, name: str) -> Path | None:
    """``plan_dir / name`` if it is a regular file of the plan folder itself: not a symbolic link (whatever it
    points to), and resolving inside the folder (the rule the service's artifact storage follows); else None.
    A plan folder holding ``plan.json -> /etc/passwd`` serves nothing of the machine's other files."""
    root = plan_dir.resolve()
    path = root / name
    try:
        if path.is_symlink():
            return None
        resolved = path.resolve(strict=True)
    except (OSError, RuntimeError):
        return None
    if resolved.parent != root or not resolved.is_file():
        return None
    return resolved


def free_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def view(plan_dir: str, *, host: str = "127.0.0.1", port: int = 0, open_browser: bool = False) -> int:
    """Serve the viewer of ``plan_dir`` until interrupted; print its address. Returns an exit status."""
    from scanmill.viewer import VendorMissing, check_vendor

    d = Path(plan_dir)
    if not (d / "viewer.json").is_file():
        why = "is not a directory" if not d.is_dir() else \
            "has no viewer.json (a plan written before the viewer existed, or not a plan directory: plan it again)"
        print(f"error [not_a_plan]: {d} {why}.", file=sys.stderr)
        return 2
    try:
        check_vendor()
    except VendorMissing as exc:
        print(f"error [viewer_not_installed]: {exc}", file=sys.stderr)
        return 2
    import uvicorn

    key = secrets.token_urlsafe(24)
    port = port or free_port(host)
    url = f"http://{host}:{port}/#key={key}"
    print(f"scanmill view: {url}\n  (the plan in {d.resolve()}; Ctrl-C stops)", flush=True)
    if open_browser:
        import webbrowser
        webbrowser.open(url)
    uvicorn.run(create_local_app(d.resolve(), key), host=host, port=port, log_level="warning")
    return 0
