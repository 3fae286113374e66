"""How the suite is spread over pytest-xdist's workers (``-n 2 --dist loadgroup``, set in pyproject.toml).

- Tests that share a module- or class-scoped fixture defined in their own test file (a simulated log and the
  model identified on it, say) run on one worker, so that the fixture is built once, not once per worker:
  they get an ``xdist_group`` named after their file.
- Tests marked ``slow`` are collected first: the scheduler hands the long ones out while there is still
  short work to balance them with, instead of leaving one of them for the end on a single worker.

Without xdist (``-n 0``, or the plugin absent) the same order holds and the groups are unused marks.
"""

from __future__ import annotations

import pytest

SHARED_SCOPES = ("module", "class")


def shares_a_fixture_of_its_file(item: pytest.Item) -> bool:
    """Whether ``item`` uses a module- or class-scoped fixture defined in its own test file."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    module = item.nodeid.split("::", 1)[0]
    for defs in info.name2fixturedefs.values():
        fixture = defs[-1]
        if fixture.scope in SHARED_SCOPES and fixture.baseid.split("::", 1)[0] == module:
            return True
    return False


@pytest.hookimpl(tryfirst=True)  # before xdist reads the xdist_group marks into the node ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    groups: dict[pytest.Item, str] = {}
    for item in items:
        if shares_a_fixture_of_its_file(item):
            groups[item] = item.nodeid.split("::", 1)[0]
            item.add_marker(pytest.mark.xdist_group(groups[item]))
    slow_groups = {groups[item] for item in items if item in groups and item.get_closest_marker("slow")}

    def later(item: pytest.Item) -> bool:  # a group moves as one, so that its fixture is still built once
        return item.get_closest_marker("slow") is None and groups.get(item) not in slow_groups

    items.sort(key=later)  # stable: slow first, otherwise as collected
