"""Suite-wide collection order for the parallel run (issue 28).

The README's test command runs the suite on every core (``-n auto`` in pyproject.toml's
``addopts``, pytest-xdist). The tests marked ``slow`` (each needs more than 10 s on the 2-core
machine, and says why beside its mark) are collected first, so that the workers start them
while the many short tests are still queued behind: a slow test started last would hold one
worker alone at the end of the run. The order within each group is the files' own.
"""

from __future__ import annotations


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
