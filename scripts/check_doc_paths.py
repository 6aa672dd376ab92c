"""Check that the repository paths the docs name exist, and that README links resolve.

MkDocs' strict build (scripts/docs.sh) checks the links between pages of docs/. This
checks what it cannot: the paths written in code spans and code blocks (configs,
scripts, source files: `configs/mompo/dst.toml`, `agent/src/{algo,nets}/`), in the
pages and in the Markdown files outside docs/, and the relative links of those
files (README.md links into docs/). A path counts as found relative to the
repository root or to env_server/ (where its own commands run). Placeholders
(`<time>`), globs and run outputs (`runs/...`) are not checked. CHANGELOG.md is left
out: it names files as they were.

    .venv/bin/python scripts/check_doc_paths.py    # exits 1 and lists what is missing
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BASES = (ROOT, ROOT / "env_server")
OUTSIDE_DOCS = ("README.md", "env_server/README.md", "deploy/README.md", "examples/plugin/README.md")
TOP = ("agent", "configs", "deploy", "docs", "env_server", "examples", "proto", "scripts", "tests")
# A comma separates paths (`--results a.csv,b.csv`) except inside braces (`{algo,nets}`).
PATH = re.compile(r"(?<![\w./-])((?:" + "|".join(TOP) + r")/(?:[\w./<>*-]|\{[^{}\s]*\})*)")
CODE = re.compile(r"```.*?```|`[^`\n]+`", re.S)
LINK = re.compile(r"\]\(([^)\s]+)\)")


def expand(path: str) -> list[str]:
    """`a/{b,c}.rs` -> `a/b.rs`, `a/c.rs` (one level of braces at a time)."""
    m = re.search(r"\{([^{}]*)\}", path)
    if not m:
        return [path]
    return [p for alt in m.group(1).split(",") for p in expand(path[: m.start()] + alt + path[m.end() :])]


def exists(path: str) -> bool:
    """A file or folder, or a Rust module named without its `.rs` (`agent/src/{eval,plot}`)."""
    if re.fullmatch(r"env_server/[\w-]+", path) and not (ROOT / path).exists():
        return True  # gymnasium's "env_server/<id>" names, not paths
    return any((base / p).exists() for base in BASES for p in (path, path + ".rs"))


def missing_paths(text: str) -> list[str]:
    missing = []
    for span in CODE.findall(text):
        for raw in PATH.findall(span):
            path = raw.rstrip(".,:;")
            if any(c in raw for c in "<*") or path.endswith("-"):
                continue
            for p in expand(path):
                if not exists(p):
                    missing.append(p)
    return missing


def broken_links(md: Path, text: str) -> list[str]:
    broken = []
    for target in LINK.findall(CODE.sub("", text)):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        if not (md.parent / target.split("#")[0]).exists():
            broken.append(target)
    return broken


def markdown_pages() -> list[Path]:
    """The site's pages and the Markdown files outside docs/ (CHANGELOG.md left out)."""
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / f for f in OUTSIDE_DOCS]


def main() -> int:
    pages = markdown_pages()
    problems = []
    for md in pages:
        text = md.read_text()
        name = md.relative_to(ROOT)
        problems += [f"{name}: names {p}, which does not exist" for p in missing_paths(text)]
        if str(name) in OUTSIDE_DOCS:
            problems += [f"{name}: links to {t}, which does not exist" for t in broken_links(md, text)]
    return report(problems, f"checked the paths named in {len(pages)} Markdown files: {len(problems)} missing")


def report(problems: list[str], summary: str) -> int:
    """Prints each problem and the summary line; the exit status: 1 if there were any."""
    for p in problems:
        print(p)
    print(summary)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
