"""Shared rules of the drivers: experiments.names.by_name (their tables of named things) and
experiments.report.markdown_table (their Markdown tables)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from experiments.axes import AXES
from experiments.configs import CONFIGS
from experiments.names import by_name
from experiments.studies.breaks import PROFILE_AXES


@dataclass(frozen=True)
class _Item:
    name: str
    value: int = 0


def test_items_are_keyed_by_their_name_in_the_order_given() -> None:
    table = by_name(_Item("b", 1), _Item("a", 2))
    assert list(table) == ["b", "a"] and table["a"].value == 2


def test_a_name_given_twice_is_refused_not_overwritten() -> None:
    with pytest.raises(ValueError, match="'a' is given twice"):
        by_name(_Item("a", 1), _Item("b"), _Item("a", 2))


@pytest.mark.parametrize("table", [AXES, PROFILE_AXES, CONFIGS], ids=["axes", "profile", "sweep"])
def test_the_drivers_tables_are_keyed_by_name(table: dict) -> None:
    assert table and all(key == item.name for key, item in table.items())


def test_a_markdown_table_has_its_rule_and_refuses_a_ragged_row() -> None:
    from experiments.report import markdown_table

    assert markdown_table(["a", "b"], [(1, "x"), ("y", 2.5)]).splitlines() == [
        "| a | b |",
        "|---|---|",
        "| 1 | x |",
        "| y | 2.5 |",
    ]
    with pytest.raises(ValueError, match="a row of 1 cells under a header of 2"):
        markdown_table(["a", "b"], [("only",)])
