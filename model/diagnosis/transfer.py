"""Does the bench's model-error correction carry to the field log?

``diagnose`` judges the field against the nominal model plus the correction learned on the bench
(``model.model_error``), with the correction's cross-validated bench error as the model's known error.
That error is measured on one realisation of the bench input; on a rig whose memory is deeper than the
correction holds, another realisation (the field) can show much more of it, and an effect is then named
for what is only the model's own error. The correction's gain can be measured on the field itself: the
drop of the squared error from the bare model to the corrected one, here, against the drop the bench's
cross-validation measured. When the field shows significantly less (one-sided, on the scored chunks'
means: their standard error from their effective number, ``stats.effective_n``, and Student's t
on that number less one, since so few correlated means understate their own memory), the part that
did not carry is model error the bench could not see, and the floor an effect must clear is raised by
it. The bench's gain is taken as exact: MODEL.json keeps no spread of it.

An effect changes the residual the correction works on, so the drop is measured twice: on the nominal
(the screen: the check runs only when that drop is short) and on the verdict's fitted effects (the
effects being explained, what is left is the correction's). The floor rises by the smaller of the two
shortfalls, and only when both are significant. No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from warpbridge.model.diagnosis.options import Decision, DiagnoseOptions
from warpbridge.model.diagnosis.problem import Fit, Problem
from warpbridge.model.diagnosis.search import Explorer
from warpbridge.model.diagnosis.selection import Path, decide
from warpbridge.model.diagnosis.stats import effective_n
from warpbridge.model.model_error import ErrorModel


@dataclass(frozen=True)
class Transfer:
    """The correction's gain (deg^2, drop of the mean squared error from bare to corrected) on the bench
    (cross-validated) and on the field's scored samples, its standard error there, and the one-sided p of
    the field's gain being the bench's."""

    bench_gain: float
    field_gain: float
    se: float
    p_value: float
    alpha: float = DiagnoseOptions.transfer_alpha  # the level ``short`` is judged at

    @property
    def shortfall(self) -> float:
        """What the field shows less of the bench's gain (deg^2; 0 when it shows as much or more)."""
        return max(self.bench_gain - self.field_gain, 0.0)

    @property
    def short(self) -> bool:
        """The field shows significantly less of the correction's gain than the bench."""
        return self.shortfall > 0.0 and self.p_value < self.alpha

    def to_dict(self) -> dict:
        return {"bench_gain_ms": self.bench_gain, "field_gain_ms": self.field_gain, "se_ms": self.se,
                "p_value": self.p_value}


def mean_se(x: np.ndarray) -> tuple[float, float]:
    """Standard error of the mean of a correlated series and the degrees of freedom it is worth (its
    effective number of independent samples less one); (inf, 0) for fewer than two."""
    x = np.asarray(x, dtype=np.float64)
    if x.size < 2:
        return math.inf, 0.0
    n_eff = effective_n(x)
    return math.sqrt(float(np.var(x)) / n_eff), max(n_eff - 1.0, 1.0)


def transfer(w: np.ndarray, w_bare: np.ndarray, w_corrected: np.ndarray, chunks: np.ndarray,
             bench_gain: float, alpha: float = DiagnoseOptions.transfer_alpha) -> Transfer:
    """The correction's gain on the scored chunks (``chunks >= 0``) of a log with measured warp ``w``, the
    model's prediction without (``w_bare``) and with (``w_corrected``) the correction, against
    ``bench_gain``."""
    g = (w - w_bare) ** 2 - (w - w_corrected) ** 2
    labels = np.unique(chunks[chunks >= 0])
    if labels.size < 4 or not np.all(np.isfinite(g[chunks >= 0])):
        return Transfer(bench_gain, math.nan, math.inf, 1.0, alpha)
    sums = np.bincount(chunks[chunks >= 0], weights=g[chunks >= 0])
    counts = np.bincount(chunks[chunks >= 0])
    means = sums[labels] / counts[labels]
    field_gain = float(np.sum(sums[labels]) / np.sum(counts[labels]))
    se, dof = mean_se(means)
    if not (se > 0 and math.isfinite(se)):
        return Transfer(bench_gain, field_gain, se, 0.0 if field_gain < bench_gain else 1.0, alpha)
    p = float(stats.t.sf((bench_gain - field_gain) / se, dof))
    return Transfer(bench_gain, field_gain, se, p, alpha)


def raised_floor(nominal: Transfer, verdict: Transfer) -> float:
    """What the floor (deg^2) rises by: the smaller shortfall, when both the nominal's and the verdict's are
    significant; 0 otherwise."""
    if not (nominal.short and verdict.short):
        return 0.0
    return min(nominal.shortfall, verdict.shortfall)


@dataclass
class Carry:
    """Whether the bench's model-error correction carries to this log (``model.diagnosis.transfer``): the same
    problem without the correction, the correction's bench gain, its gain on the nominal here, and what
    the known error already holds beyond the bench's (deg^2: a check log of another input measured it)."""

    bare: Problem
    bench_gain: float
    nominal: Transfer
    measured_ms: float = 0.0

    def of(self, ex: Explorer, fit: Fit) -> Transfer:
        """The correction's gain here given ``fit``'s effects."""
        return transfer(ex.w, self.bare.predict(fit.effects), fit.w_pred, ex.prob.split.chunks, self.bench_gain,
                        ex.opt.transfer_alpha)

    def raise_for(self, ex: Explorer, path: Path) -> tuple[float, Transfer]:
        """What the floor rises by (deg^2) for ``path``'s verdict, beyond what the known error already
        holds, and the correction's gain given the verdict's effects."""
        tr = self.of(ex, path.fit) if path.selected else self.nominal
        return max(raised_floor(self.nominal, tr) - self.measured_ms, 0.0), tr


def carry_check(ex: Explorer, em: ErrorModel | None, slack_side: float, measured_ms: float = 0.0) -> Carry | None:
    """The transfer check of the correction ``em`` on the explorer's log, whose nominal takes up its slack
    on ``slack_side`` (None without a correction); ``measured_ms`` is what the known error already holds
    beyond the bench's (``identify --check``): a shortfall raises the floor only past it."""
    prob = ex.prob
    if em is None or prob.error_model is None or not (
            math.isfinite(em.rms_before_deg) and math.isfinite(em.rms_after_deg)):
        return None
    bare = Problem(prob.t, prob.u, prob.w, prob.airspeed, prob.params, prob.base, prob.z0, split=prob.split,
                   error_model=None, slack_side=slack_side)
    bench_gain = em.rms_before_deg ** 2 - em.rms_after_deg ** 2
    nominal = transfer(ex.w, bare.predict(ex.base), ex.nominal.w_pred, prob.split.chunks, bench_gain,
                       ex.opt.transfer_alpha)
    return Carry(bare, bench_gain, nominal, max(measured_ms, 0.0))


@dataclass(frozen=True)
class Carried:
    """What ``decide_carried`` raised the floor by (deg^2) for its verdict, whether that raise settled, and
    the correction's gain on the nominal and given the verdict's effects."""

    raised_by_ms: float
    settled: bool
    nominal: Transfer
    verdict: Transfer

    def to_dict(self) -> dict:
        return {"raised_by_ms": self.raised_by_ms, "settled": self.settled, "nominal": self.nominal.to_dict(),
                "verdict": self.verdict.to_dict()}


def decide_carried(ex: Explorer, d: Decision, max_effects: int, carry: Carry | None) -> tuple[Path, Carried | None]:
    """``decide``, then, when the correction's gain on the nominal falls significantly short of the bench's,
    the same with the floor raised by what it did not carry given the verdict's effects (the smaller of
    the two shortfalls, both significant), until the raise a verdict asks for is the one it was decided
    at. When a verdict asks for less than its floor, the lower floor is tried: its verdict is taken if it
    is the same one; else the higher floor's stands (the verdict that names less). Each raised floor is
    judged on a view of ``ex`` (``Explorer.at_floor``), which is left as it was; the second value says what
    was raised and whether it settled (None: the correction carries, or there is none)."""
    path = decide(ex, d, max_effects)
    if carry is None or not carry.nominal.short:
        return path, None
    extra, settled = 0.0, False
    for _ in range(ex.opt.carry_rounds):
        up, tr = carry.raise_for(ex, path)
        if math.isclose(up, extra, rel_tol=1e-9, abs_tol=1e-15):
            settled = True
            break
        lower = decide(ex.at_floor(ex.floor2 + up), d, max_effects)
        if up < extra:  # the verdict asks for less than the floor it was decided at
            if lower.named == path.named:
                path, extra = lower, up
                up, tr = carry.raise_for(ex, path)
                settled = math.isclose(up, extra, rel_tol=1e-9, abs_tol=1e-15)
            break
        path, extra = lower, up
    else:
        up, tr = carry.raise_for(ex, path)
        settled = math.isclose(up, extra, rel_tol=1e-9, abs_tol=1e-15)
    return path, Carried(extra, settled, carry.nominal, tr)
