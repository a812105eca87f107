#!/usr/bin/env python3
"""Vendor three.js for the browser viewer (scanmill/viewer/static/vendor/three/), at build time.

The viewer page loads three.js from the package itself, not from a CDN: the service runs on machines
without internet access and the page must work there. The files are not committed (the directory is
in .gitignore); this script fetches them from the npm registry, the one place they are published,
with the standard library only, so that a bare Debian machine needs neither node nor npm.

What it does:
  * downloads the pinned tarball (THREE_VERSION) from the registry, or reads it with --from-tarball;
  * checks it against the pinned sha512 integrity (the registry's `dist.integrity`, an SRI string)
    and refuses to install anything on a mismatch, so a changed or corrupted tarball never lands;
  * extracts exactly the files in FILES, nothing else, by name, so no path in the archive can
    write outside the destination;
  * writes them with a VERSION file (version and integrity) into a temporary directory beside the
    destination and renames it into place, so a reader never sees half a vendor directory;
  * does nothing when VERSION already matches (safe to run on every setup, and offline).

OrbitControls.js is kept byte for byte: it imports from the bare specifier 'three', which the
viewer page resolves with an import map.

Exit status: 0 installed or already there, 1 integrity mismatch or a broken tarball, 2 the tarball
could not be obtained (offline, registry unreachable, --from-tarball path missing). With --check:
0 when the pinned release is in place, 1 when not, and nothing is changed.

To move to another three.js release: `npm view three@X.Y.Z dist.integrity` (or the registry's JSON at
https://registry.npmjs.org/three/X.Y.Z), then change THREE_VERSION and THREE_INTEGRITY together.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import hashlib
import hmac
import io
import os
import shutil
import sys
import tarfile
import tempfile
import urllib.error
import urllib.request
from pathlib import Path

THREE_VERSION = "0.187.0"
# `npm view three@0.187.0 dist.integrity`: the registry's sha512 of the tarball, base64 (SRI format).
THREE_INTEGRITY = "sha512-Qiu7R+Cmh8CstZsY1uJOSWnVlfo7ZtNLV7mF8Jltk3LB3AtDu9cRZlcnRKkAk8Y4z6KKw35z7Y7Urd7jWY8etA=="
DEFAULT_REGISTRY = "https://registry.npmjs.org"

# Path in the npm tarball -> name in the vendor directory. The npm package of three 0.187.0 has no
# minified build (build/ holds three.module.js, three.core.js, three.cjs, the WebGPU/TSL builds): the
# ES module entry point three.module.js imports the bulk of the library from './three.core.js', so
# both are vendored, side by side, and the page's import map points "three" at three.module.js.
FILES = {
    "package/build/three.module.js": "three.module.js",
    "package/build/three.core.js": "three.core.js",
    "package/examples/jsm/controls/OrbitControls.js": "OrbitControls.js",
    "package/LICENSE": "LICENSE",
}
VERSION_FILE = "VERSION"

REPO = Path(__file__).resolve().parent.parent
DEFAULT_DEST = REPO / "scanmill" / "viewer" / "static" / "vendor" / "three"


class VendorError(Exception):
    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.status = status


def tarball_url(registry: str, version: str = THREE_VERSION) -> str:
    return f"{registry.rstrip('/')}/three/-/three-{version}.tgz"


def version_text(version: str = THREE_VERSION, integrity: str = THREE_INTEGRITY) -> str:
    return f"three {version}\n{integrity}\n"


def is_current(dest: Path) -> bool:
    """True when dest holds this pinned release: VERSION matches and every vendored file is there."""
    try:
        if (dest / VERSION_FILE).read_text(encoding="utf-8") != version_text():
            return False
    except OSError:
        return False
    return all((dest / name).is_file() and (dest / name).stat().st_size > 0 for name in FILES.values())


def check_integrity(data: bytes, integrity: str = THREE_INTEGRITY) -> None:
    algo, _, expected = integrity.partition("-")
    if algo != "sha512" or not expected:
        raise VendorError(f"vendor_three: unsupported integrity string {integrity!r} (want sha512-...)", 1)
    actual = base64.b64encode(hashlib.sha512(data).digest()).decode("ascii")
    if not hmac.compare_digest(actual, expected):
        raise VendorError(
            "vendor_three: INTEGRITY MISMATCH for the three.js tarball - refusing to install it.\n"
            f"  expected sha512-{expected}\n"
            f"  got      sha512-{actual} ({len(data)} bytes)\n"
            "  The download was corrupted or altered (a proxy, a mirror, a different file given to "
            "--from-tarball). Nothing was changed.", 1)


def download(url: str, timeout: float) -> bytes:
    request = urllib.request.Request(url, headers={"User-Agent": "scanmill-vendor-three"})
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            return response.read()
    except urllib.error.HTTPError as exc:
        raise VendorError(f"vendor_three: {url} answered HTTP {exc.code} {exc.reason}", 2) from exc
    except (urllib.error.URLError, OSError) as exc:  # DNS failure, refused, timeout, TLS, reset
        reason = getattr(exc, "reason", exc)
        raise VendorError(
            f"vendor_three: cannot download three.js {THREE_VERSION} from {url}: {reason}\n"
            "  This machine seems to be offline or cannot reach the npm registry. Either give it access\n"
            "  (an HTTPS_PROXY in the environment is honoured), or download the tarball elsewhere\n"
            f"  ({tarball_url(DEFAULT_REGISTRY)}) and run:\n"
            f"    python3 scripts/vendor_three.py --from-tarball three-{THREE_VERSION}.tgz\n"
            f"  (through scripts/setup.sh: SCANMILL_THREE_TARBALL=/path/to/three-{THREE_VERSION}.tgz)", 2) from exc


def extract(data: bytes) -> dict[str, bytes]:
    """The bytes of each wanted file, read by exact name (nothing else in the archive is touched)."""
    out = {}
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
            for member_name, name in FILES.items():
                try:
                    member = tar.getmember(member_name)
                except KeyError:
                    raise VendorError(f"vendor_three: {member_name} is missing from the tarball", 1) from None
                if not member.isfile():
                    raise VendorError(f"vendor_three: {member_name} in the tarball is not a regular file", 1)
                fileobj = tar.extractfile(member)
                assert fileobj is not None
                out[name] = fileobj.read()
    except (tarfile.TarError, EOFError, OSError) as exc:
        raise VendorError(f"vendor_three: the tarball cannot be read: {exc}", 1) from exc
    return out


def install(files: dict[str, bytes], dest: Path) -> None:
    """Write files and VERSION into a temporary sibling of dest, then rename it into place."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}-new-", dir=dest.parent))
    old = None
    try:
        for name, content in files.items():
            (tmp / name).write_bytes(content)
            os.chmod(tmp / name, 0o644)
        # VERSION last: a directory with a matching VERSION is complete.
        (tmp / VERSION_FILE).write_text(version_text(), encoding="utf-8")
        os.chmod(tmp / VERSION_FILE, 0o644)
        os.chmod(tmp, 0o755)  # mkdtemp makes it 0700; the installed package must be readable by all
        if dest.exists() or dest.is_symlink():
            # rename() cannot replace a non-empty directory: move the old one aside first, then drop it.
            old = Path(tempfile.mkdtemp(prefix=f".{dest.name}-old-", dir=dest.parent))
            os.rename(dest, old / dest.name)
        os.rename(tmp, dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def locked(dest: Path):
    """Serialise concurrent runs (two setups at once): the rename dance in install() is not re-entrant."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock, as before
        yield
        return
    with open(dest.parent / f".{dest.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def vendor(dest: Path, force: bool = False, from_tarball: Path | None = None,
           registry: str = DEFAULT_REGISTRY, timeout: float = 60.0, quiet: bool = False) -> bool:
    """Install the pinned three.js files into dest; False when they were already there."""
    say = (lambda msg: None) if quiet else (lambda msg: print(msg, flush=True))
    if not force and is_current(dest):
        say(f"vendor_three: three.js {THREE_VERSION} already in {dest}")
        return False
    with locked(dest):
        if not force and is_current(dest):  # another run installed it while this one waited
            say(f"vendor_three: three.js {THREE_VERSION} already in {dest}")
            return False
        return _fetch_and_install(dest, from_tarball, registry, timeout, say)


def _fetch_and_install(dest: Path, from_tarball: Path | None, registry: str, timeout: float, say) -> bool:
    if from_tarball is not None:
        try:
            data = from_tarball.read_bytes()
        except OSError as exc:
            raise VendorError(f"vendor_three: cannot read --from-tarball {from_tarball}: {exc.strerror or exc}", 2) from exc
        source = str(from_tarball)
    else:
        source = tarball_url(registry)
        say(f"vendor_three: downloading {source}")
        data = download(source, timeout)
    check_integrity(data)
    install(extract(data), dest)
    say(f"vendor_three: three.js {THREE_VERSION} ({', '.join(FILES.values())}) -> {dest} (from {source}, integrity checked)")
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dest", type=Path, default=DEFAULT_DEST,
                        help="vendor directory (default: scanmill/viewer/static/vendor/three in this checkout)")
    parser.add_argument("--force", action="store_true", help="install again even if VERSION already matches")
    parser.add_argument("--from-tarball", type=Path, metavar="PATH",
                        help=f"install from a downloaded three-{THREE_VERSION}.tgz instead of the registry "
                             "(offline; the same integrity check applies)")
    parser.add_argument("--registry", default=os.environ.get("SCANMILL_NPM_REGISTRY", DEFAULT_REGISTRY),
                        help="npm registry base URL, for a mirror (default: $SCANMILL_NPM_REGISTRY or %(default)s); "
                             "the pinned integrity is checked whatever the source")
    parser.add_argument("--timeout", type=float, default=60.0, help="download timeout in seconds (default 60)")
    parser.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    parser.add_argument("--check", action="store_true",
                        help="change nothing: exit 0 when the pinned release is already in place, 1 when not")
    args = parser.parse_args(argv)
    if args.check:
        return 0 if is_current(args.dest) else 1
    try:
        vendor(args.dest, force=args.force, from_tarball=args.from_tarball,
               registry=args.registry, timeout=args.timeout, quiet=args.quiet)
    except VendorError as exc:
        print(exc, file=sys.stderr)
        return exc.status
    return 0


if __name__ == "__main__":
    sys.exit(main())
