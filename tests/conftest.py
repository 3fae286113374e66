"""How the suite is spread over pytest-xdist's workers (``-n auto --dist loadgroup``, set in pyproject.toml).

- ``-n auto`` means two workers, or one per core where there are fewer, for a run of the suite or of a folder
  (``PYTEST_XDIST_AUTO_NUM_WORKERS`` or ``-n N`` say otherwise); a run of a single file or test stays in one
  process, where starting the workers would cost more than they save.
- Tests that share a module- or class-scoped fixture defined in their own test file (a simulated log and the
  model identified on it, say) run on one worker, so that the fixture is built once, not once per worker:
  they get an ``xdist_group`` named after their file.
- Tests marked ``slow`` are collected first: the scheduler hands the long ones out while there is still
  short work to balance them with, instead of leaving one of them for the end on a single worker.

Without xdist (``-n 0``, or the plugin absent) the same order holds and the groups are unused marks.
"""

from __future__ import annotations

import os

import pytest

SHARED_SCOPES = ("module", "class")
MAX_WORKERS = 2  # measured on two cores; tests that run three processes in real time want a core each besides


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """Workers for ``-n auto`` (see the module docstring); None leaves the choice to the environment variable."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    args = [a for a in config.args if not a.startswith("-")]
    if len(args) == 1 and ("::" in args[0] or args[0].endswith(".py")):
        return 0
    n = min(MAX_WORKERS, cores())
    return n if n > 1 else 0


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
