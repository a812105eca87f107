"""The plan viewer (issue 20): one HTML page with three.js, served by the service for a job
(``GET /jobs/{id}/viewer``) and by ``scanmill view PLAN_DIR`` for a plan on disk.

The page holds no plan data. It fetches ``viewer.json``, ``viewer.points.bin`` and ``viewer.paths.bin``
(:mod:`planning.report.viewer_data`) from an artifacts address with the API key as an
``Authorization: Bearer`` header, the same authentication as every other job request; the key is typed
once into the page (or handed over in the address's fragment, which browsers never send) and kept
in the tab's ``sessionStorage``. three.js is vendored into ``static/vendor/three`` at set-up
(``scripts/vendor_three.py``, from the npm registry with its licence): nothing is loaded from a CDN,
so the page works on an offline shop floor.
"""

from __future__ import annotations

import base64
import hashlib
import html
import re
from pathlib import Path

__all__ = ["STATIC_DIR", "VendorMissing", "check_vendor", "page_html"]

STATIC_DIR = Path(__file__).resolve().parent / "static"
VENDOR_FILES = ("three.module.js", "three.core.js", "OrbitControls.js", "LICENSE")


class VendorMissing(RuntimeError):
    """three.js was not vendored into the package (set-up not run)."""


def check_vendor() -> None:
    """Raise :class:`VendorMissing` with the command that fixes it when three.js is absent."""
    vendor = STATIC_DIR / "vendor" / "three"
    missing = [f for f in VENDOR_FILES if not (vendor / f).is_file()]
    if missing:
        raise VendorMissing(f"the viewer's three.js files are not installed ({', '.join(missing)} missing in "
                            f"{vendor}); run `python3 scripts/vendor_three.py` (or `make setup-run`) once with "
                            "access to the npm registry, or `python3 scripts/vendor_three.py --from-tarball "
                            "three-0.187.0.tgz` offline.")


def page_html(*, artifacts_base: str, static_base: str, title: str) -> tuple[str, dict[str, str]]:
    """The viewer page for the data under ``artifacts_base`` (an absolute path ending in ``/``) and its
    response headers: no caching of a page naming a job, no framing, no referrer, and a content
    security policy that allows only this origin's scripts (plus the page's import map, by its hash)
    and connections: nothing is fetched from elsewhere and nothing leaves for elsewhere."""
    text = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
    for name, value in (("{{ARTIFACTS}}", artifacts_base), ("{{STATIC}}", static_base), ("{{TITLE}}", title)):
        text = text.replace(name, html.escape(value, quote=True))
    m = re.search(r'<script type="importmap">(.*?)</script>', text, re.DOTALL)
    digest = base64.b64encode(hashlib.sha256(m.group(1).encode()).digest()).decode() if m else ""
    headers = {
        "Cache-Control": "no-store",
        "X-Frame-Options": "DENY",
        "Referrer-Policy": "no-referrer",
        "X-Content-Type-Options": "nosniff",
        "Content-Security-Policy": (f"default-src 'self'; script-src 'self' 'sha256-{digest}'; "
                                    "style-src 'self' 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; "
                                    "frame-ancestors 'none'; base-uri 'none'; form-action 'none'"),
    }
    return text, headers
