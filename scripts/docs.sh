#!/usr/bin/env bash
# Build the documentation site (docs/, mkdocs.yml) strictly into target/site: a link to
# a missing page or heading, or a page outside the nav, fails. Then check that the
# repository paths the README and the pages name (configs, scripts, source files)
# exist, and that the README's own links resolve (scripts/check_doc_paths.py).
# Last, that every Markdown table has its separator row and rows of its header's width
# (scripts/check_doc_tables.py).
# scripts/test.sh runs this beside the lints; run it alone after editing docs.
set -euo pipefail
cd "$(dirname "$0")/.."
# mkdocs-material prints a notice about MkDocs 2.0 on every build; it is not a warning
# about this site. No --quiet: it hides the warnings that --strict counts, so a broken
# link would pass.
NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict
.venv/bin/python scripts/check_doc_paths.py
.venv/bin/python scripts/check_doc_tables.py
