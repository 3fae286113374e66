"""The verdict's effects sized again on every analysed sample, once the scored blocks have chosen them."""

from __future__ import annotations

from collections.abc import Callable

from warpbridge.model.diagnosis.problem import Fit, Problem
from warpbridge.model.diagnosis.selection import Path


class WholeLogSizes:
    """Each verdict's effects sized on the whole analysed log (``Problem.refit_whole``), once per distinct fit;
    a verdict of no effect is its own fit."""

    def __init__(self, prob: Problem, max_evals: int, progress: Callable[[str, int, int], None] | None) -> None:
        self.prob, self.max_evals, self.progress = prob, max_evals, progress
        self._done: dict[str, Fit] = {}

    @staticmethod
    def _key(p: Path) -> str:
        return repr((p.selected, p.fit.effects))

    def expect(self, paths: list[Path]) -> None:
        """Refit every distinct verdict of ``paths`` now, with progress."""
        todo = {self._key(p): p for p in paths if p.selected and self._key(p) not in self._done}
        for k, (key, p) in enumerate(todo.items()):
            if self.progress:
                self.progress("sizing on the whole log", k, len(todo))
            self._done[key] = self.prob.refit_whole(p.fit, self.max_evals)

    def of(self, p: Path) -> Fit:
        if not p.selected:
            return p.fit
        self.expect([p])
        return self._done[self._key(p)]
