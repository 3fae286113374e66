"""How the suite is spread over pytest-xdist's workers (``-n auto --dist loadgroup``, set in pyproject.toml).

- ``-n auto`` means two workers, or one per core where there are fewer, for a run of the suite or of a folder
  (``PYTEST_XDIST_AUTO_NUM_WORKERS`` or ``-n N`` say otherwise); a run of a single file or test stays in one
  process, where starting the workers would cost more than they save.
- A test file that defines a module-, class- or session-scoped fixture (a simulated log and the model identified
  on it, a built wheel) runs on one worker, so that the fixture is built once, not once per worker; the tests of
  the other files are handed out one at a time. (xdist's own ``xdist_group`` marks rename the node ids, which
  pytest 9 no longer allows: the scheduler below groups by file instead.)
- In a worker numba fits on one thread: the workers keep the cores busy, and numba's threads on top of them
  would only contend for the same cores.
- Tests marked ``slow`` are collected first, with the rest of their file when it is grouped: the scheduler hands
  the long ones out while there is still short work to balance them with.
"""

from __future__ import annotations

import os
import re
from functools import cache
from pathlib import Path

import pytest

MAX_WORKERS = 2  # measured on two cores; tests that run three processes in real time want a core each besides
SHARED_FIXTURE = re.compile(r"""@pytest\.fixture\(\s*scope\s*=\s*["'](?:module|class|session)["']""")


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def pytest_configure(config: pytest.Config) -> None:
    """In an xdist worker, numba fits on one thread (unless ``NUMBA_NUM_THREADS`` says otherwise): the workers
    already keep the cores busy, and numba's own threads on top of them only contend for the same cores."""
    if os.environ.get("PYTEST_XDIST_WORKER") and "NUMBA_NUM_THREADS" not in os.environ:
        os.environ["NUMBA_NUM_THREADS"] = "1"


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


@cache
def shares_fixtures(root: Path, module: str) -> bool:
    """Whether the test file ``module`` (relative to ``root``) defines a fixture broader than a test."""
    try:
        return SHARED_FIXTURE.search((root / module).read_text(encoding="utf-8")) is not None
    except OSError:
        return False


def pytest_xdist_make_scheduler(config: pytest.Config, log):  # noqa: ANN201 - xdist's scheduler type
    """For ``--dist loadgroup``: each test its own unit of work, except the files that share a fixture."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    root = config.rootpath

    class SharedFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if shares_fixtures(root, module) else nodeid

    return SharedFixtureScheduling(config, log)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    root = config.rootpath
    slow_files = {item.nodeid.split("::", 1)[0] for item in items if item.get_closest_marker("slow")}

    def later(item: pytest.Item) -> bool:  # a grouped file moves as one, so that its fixtures are built once
        module = item.nodeid.split("::", 1)[0]
        if shares_fixtures(root, module):
            return module not in slow_files
        return item.get_closest_marker("slow") is None

    items.sort(key=later)  # stable: slow first, otherwise as collected


@pytest.fixture
def saved_figures(monkeypatch: pytest.MonkeyPatch) -> list:
    """Every matplotlib figure the test saves, in order (each is still written to its file)."""
    from matplotlib.figure import Figure

    figures: list = []
    save = Figure.savefig

    def keep(self, *a, **k):
        figures.append(self)
        return save(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    return figures
