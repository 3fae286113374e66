"""Does the bench's model-error correction carry to the field log?

``diagnose`` judges the field against the nominal model plus the correction learned on the bench
(``model.model_error``), with the correction's cross-validated bench error as the model's known error.
That error is measured on one realisation of the bench input; on a rig whose memory is deeper than the
correction holds, another realisation (the field) can show much more of it, and an effect is then named
for what is only the model's own error. The correction's gain can be measured on the field itself: the
drop of the squared error from the bare model to the corrected one, here, against the drop the bench's
cross-validation measured. When the field shows significantly less (one-sided, on the scored chunks'
means: their standard error from their effective number, ``diag_stats.effective_n``, and Student's t
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

from warpbridge.model.diag_stats import effective_n

TRANSFER_ALPHA = 0.001  # level of the one-sided test that the field shows less of the correction's gain


@dataclass(frozen=True)
class Transfer:
    """The correction's gain (deg^2, drop of the mean squared error from bare to corrected) on the bench
    (cross-validated) and on the field's scored samples, its standard error there, and the one-sided p of
    the field's gain being the bench's."""

    bench_gain: float
    field_gain: float
    se: float
    p_value: float

    @property
    def shortfall(self) -> float:
        """What the field shows less of the bench's gain (deg^2; 0 when it shows as much or more)."""
        return max(self.bench_gain - self.field_gain, 0.0)

    @property
    def short(self) -> bool:
        """The field shows significantly less of the correction's gain than the bench."""
        return self.shortfall > 0.0 and self.p_value < TRANSFER_ALPHA

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
             bench_gain: float) -> Transfer:
    """The correction's gain on the scored chunks (``chunks >= 0``) of a log with measured warp ``w``, the
    model's prediction without (``w_bare``) and with (``w_corrected``) the correction, against
    ``bench_gain``."""
    g = (w - w_bare) ** 2 - (w - w_corrected) ** 2
    labels = np.unique(chunks[chunks >= 0])
    if labels.size < 4 or not np.all(np.isfinite(g[chunks >= 0])):
        return Transfer(bench_gain, math.nan, math.inf, 1.0)
    sums = np.bincount(chunks[chunks >= 0], weights=g[chunks >= 0])
    counts = np.bincount(chunks[chunks >= 0])
    means = sums[labels] / counts[labels]
    field_gain = float(np.sum(sums[labels]) / np.sum(counts[labels]))
    se, dof = mean_se(means)
    if not (se > 0 and math.isfinite(se)):
        return Transfer(bench_gain, field_gain, se, 0.0 if field_gain < bench_gain else 1.0)
    p = float(stats.t.sf((bench_gain - field_gain) / se, dof))
    return Transfer(bench_gain, field_gain, se, p)


def raised_floor(nominal: Transfer, verdict: Transfer) -> float:
    """What the floor (deg^2) rises by: the smaller shortfall, when both the nominal's and the verdict's are
    significant; 0 otherwise."""
    if not (nominal.short and verdict.short):
        return 0.0
    return min(nominal.shortfall, verdict.shortfall)
