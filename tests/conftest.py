"""Suite-wide collection order for the parallel run (issue 28).

The README's test command runs the suite on every core (``-n auto --dist worksteal`` in
pyproject.toml's ``addopts``, pytest-xdist). The tests marked ``slow`` (each needs more than
10 s on the 2-core machine, and says why beside its mark) are collected first, the longest
first where the mark gives its measured ``seconds``: worksteal hands each worker a contiguous
share of the collection and an idle worker steals from the end of another's, so a long test
collected late would run alone at the end of the run (the million-step particle test did: the
suite took 14 min with its 4 min at the end; longest first, 14 min 31 s: the other slow
tests then wait in that worker's share). The order is otherwise the files' own.
"""

from __future__ import annotations


def _order(item) -> tuple[bool, float]:
    slow = item.get_closest_marker("slow")
    return (slow is None, -float(slow.kwargs.get("seconds", 0.0)) if slow else 0.0)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_order)
