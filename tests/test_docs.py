"""The repository stands on its own: every document the code, the CLI help and the README cite exists,
and every section they name in it is one of its headings."""

import re
import subprocess
import sys
from pathlib import Path

import scanmill

ROOT = Path(__file__).resolve().parents[1]
# docs/NAME.md, optionally followed by a quoted section name: docs/design.md "Reference cases"
CITE = re.compile(r'docs/([A-Za-z0-9_\-]+\.md)(?:[ ,(]{1,3}"([^"]{2,60})")?')


def _sources():
    tracked = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.split()
    return [ROOT / p for p in tracked if p.endswith((".py", ".md", ".toml", ".yaml", ".sh")) or p == "Makefile"]


def _headings(path: Path) -> set[str]:
    return {m.group(1).strip().lower() for m in re.finditer(r"^#+\s+(.+)$", path.read_text(), re.M)}


def test_cited_documents_and_sections_exist():
    missing = []
    cited = 0
    for src in _sources():
        if not src.exists() or src.name == "test_docs.py":
            continue
        text = src.read_text(errors="replace")
        for m in CITE.finditer(text):
            cited += 1
            doc = ROOT / "docs" / m.group(1)
            where = f"{src.relative_to(ROOT)}: docs/{m.group(1)}"
            if not doc.is_file():
                missing.append(where)
            elif m.group(2) and " ".join(m.group(2).split()).lower() not in _headings(doc):
                missing.append(f'{where} "{m.group(2)}"')
        if re.search(r"\bDESIGN\.md\b", text):
            missing.append(f"{src.relative_to(ROOT)}: DESIGN.md (not in the repository)")
    assert cited > 10, "the citation pattern found almost nothing: is it still right?"
    assert not missing, "cited but absent:\n" + "\n".join(missing)


def test_cli_help_points_to_existing_documents():
    for sub in ("plan", "sample", "serve"):
        out = subprocess.run([sys.executable, "-m", "scanmill.cli", sub, "--help"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
        for name in re.findall(r"docs/([A-Za-z0-9_\-]+\.md)", out):
            assert (ROOT / "docs" / name).is_file(), f"scanmill {sub} --help cites docs/{name}"


def test_version_flag_prints_the_package_version():
    out = subprocess.run([sys.executable, "-m", "scanmill.cli", "--version"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == f"scanmill {scanmill.__version__}"
