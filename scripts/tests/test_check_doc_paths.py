"""scripts/check_doc_paths.py: which paths a doc's code spans name, and which are missing."""

from __future__ import annotations

import check_doc_paths as check


def test_braces_expand_and_a_comma_outside_them_separates_paths():
    # Both scripts exist; the brace alternatives are two files of scripts/.
    assert check.missing_paths("`scripts/{docs,test}.sh`") == []
    text = "`--results scripts/test.sh,scripts/no-such.csv`"
    assert check.PATH.findall(text) == ["scripts/test.sh", "scripts/no-such.csv"]
    assert check.missing_paths(text) == ["scripts/no-such.csv"]
    # A sentence's comma or full stop after a path is not part of it.
    assert check.missing_paths("`scripts/test.sh`, then `scripts/docs.sh.`") == []


def test_placeholders_and_globs_are_not_checked():
    assert check.missing_paths("`configs/<name>.toml` and `configs/mompo/*.toml`") == []
