"""Check that every Markdown table in the docs renders as a table.

A table whose second line is not a separator row (`|---|---|`) renders as lines of
text with pipes in them, and a row with more or fewer cells than its header loses or
pads cells; neither is a warning in MkDocs' strict build (scripts/docs.sh), and the
first has shipped (the benchmark page's summary table, December 2026). Checks the files
scripts/check_doc_paths.py checks. A pipe inside a code span or escaped (`\\|`) is
not a cell boundary.

    .venv/bin/python scripts/check_doc_tables.py    # exits 1 and lists each bad table
"""

from __future__ import annotations

import re
import sys

from check_doc_paths import ROOT, markdown_pages, report

SEPARATOR = re.compile(r"\|(\s*:?-{3,}:?\s*\|)+")


def cells(row: str) -> int:
    """How many cells a table row has."""
    row = re.sub(r"`[^`\n]*`", "x", row).replace("\\|", "x")
    return row.strip().strip("|").count("|") + 1


def tables(text: str) -> list[list[tuple[int, str]]]:
    """Runs of lines that start with `|` outside fenced code, with their line numbers."""
    found: list[list[tuple[int, str]]] = []
    fenced, run = False, []
    for number, line in enumerate(text.split("\n") + [""], 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("|"):
            run.append((number, line))
            continue
        if run:
            found.append(run)
        run = []
    return found


def problems(text: str) -> list[str]:
    """`line N: ...` for each table without a separator row and each row of the wrong width."""
    out = []
    for table in tables(text):
        (first, header), rest = table[0], table[1:]
        if not rest or not SEPARATOR.fullmatch(rest[0][1].strip()):
            out.append(f"line {first}: a table without a separator row (|---|) under its header")
            continue
        want = cells(header)
        widths = [(number, cells(row)) for number, row in rest]
        out += [f"line {n}: a row of {got} cells under a header of {want}" for n, got in widths if got != want]
    return out


def main() -> int:
    pages = markdown_pages()
    found = [f"{md.relative_to(ROOT)}: {p}" for md in pages for p in problems(md.read_text())]
    return report(found, f"checked the tables of {len(pages)} Markdown files: {len(found)} malformed")


if __name__ == "__main__":
    sys.exit(main())
