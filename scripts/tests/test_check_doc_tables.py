"""scripts/check_doc_tables.py: a table without its separator row, or a row of the wrong
width, is found; pipes in code spans, escaped pipes and fenced code are not cells."""

from __future__ import annotations

import check_doc_tables as check

GOOD = "| a | b |\n|---|:---:|\n| `x | y` | z \\| w |\n"


def test_a_well_formed_table_passes():
    assert check.problems("text\n\n" + GOOD + "\nmore text\n") == []


def test_a_table_without_its_separator_row_is_found_at_its_first_line():
    text = "intro\n\n| a | b |\n| 1 | 2 |\n"
    assert check.problems(text) == ["line 3: a table without a separator row (|---|) under its header"]
    # A lone row is no table either.
    assert check.problems("| a | b |\n") == ["line 1: a table without a separator row (|---|) under its header"]


def test_a_row_wider_or_narrower_than_its_header_is_found():
    text = "| a | b |\n|---|---|\n| 1 | 2 | 3 |\n| 1 |\n| 1 | 2 |\n"
    assert check.problems(text) == [
        "line 3: a row of 3 cells under a header of 2",
        "line 4: a row of 1 cells under a header of 2",
    ]


def test_pipes_in_fenced_code_are_not_tables():
    assert check.problems("```sh\n| not a table\n| a | b |\n```\n") == []


def test_two_tables_one_after_the_other_are_checked_apart():
    bad = "| c |\n| 1 |\n"
    assert check.problems(GOOD + "\n" + bad) == ["line 5: a table without a separator row (|---|) under its header"]
