"""What identification returns: the model, how well it fits (training and held-out RMS against the noise
floor and a straight line), how the search went and what the log determines (``IdentResult``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.identification.checks import Support
from warpbridge.model.identification.excitation import Excitation
from warpbridge.model.identification.refine import SearchTrace
from warpbridge.model.identification.uncertainty import Uncertainty


@dataclass
class IdentResult:
    """What identification found and measured (RMS in deg)."""

    params: BoucWenParams
    train_rms: float
    heldout_rms: float
    noise: float
    linear_heldout_rms: float
    n_train: int
    n_heldout: int
    two_sided: bool
    evaluations: int
    split_time: float
    w_pred: np.ndarray = field(repr=False)
    train_mask: np.ndarray = field(repr=False)
    heldout_mask: np.ndarray = field(repr=False)
    z0: float = 0.0
    trace: SearchTrace | None = field(default=None, repr=False)
    support: Support | None = None
    delay_s: float = 0.0  # transport delay in front of the model (s): the model sees u(t - delay_s)
    travel_mm: tuple[float, float] | None = None  # the log's tendon travel (0.5 and 99.5 percentiles, mm)
    uncertainty: Uncertainty | None = field(default=None, repr=False)
    excitation: Excitation | None = None
    linear_train_rms: float = math.nan  # the best straight line's training RMS (deg)
    seed: int = 0  # the design's scramble (0: the default's)
    servo_tau_s: float = 0.0  # the servo's lag in front of the model (s): it sees u through a first-order lag
    servo_rate_mm_s: float = math.inf  # ... capped at this speed (mm/s; inf: no cap)
    servo_deadband_mm: float = 0.0  # ... to the edge of this dead band (mm; 0: none)

    def fit_dict(self) -> dict:
        d = {"train_rms_deg": self.train_rms, "heldout_rms_deg": self.heldout_rms, "noise_deg": self.noise,
             "linear_heldout_rms_deg": self.linear_heldout_rms, "n_train": self.n_train,
             "n_heldout": self.n_heldout, "split_time_s": self.split_time, "two_sided": self.two_sided,
             "evaluations": self.evaluations, "method": "variable-projection design + levenberg-marquardt",
             "z0_start_of_log": self.z0, "delay_s": self.delay_s, "servo_tau_s": self.servo_tau_s,
             "servo_rate_mm_s": self.servo_rate_mm_s if math.isfinite(self.servo_rate_mm_s) else None,
             "servo_deadband_mm": self.servo_deadband_mm,
             "linear_train_rms_deg": self.linear_train_rms,
             "design_seed": self.seed}
        if self.travel_mm is not None:
            d["travel_mm"] = list(self.travel_mm)
        if self.support is not None:
            d |= {"supported": self.support.supported, "support": self.support.reason}
        if self.trace is not None and self.trace.restarts:  # the kept model came from the next start
            d |= {"searched_again": True, "second_search_kept": self.trace.restart_kept}
        if self.trace is not None and self.trace.fold_deg is not None:
            d |= {"backbone_fold_deg": self.trace.fold_deg, "working_range_deg": list(self.trace.working_range_deg),
                  "fold_search_kept": self.trace.fold_outcome == "kept",
                  "fold_train_rms_deg": list(self.trace.fold_train_rms or ())}
        if self.trace is not None:
            d |= {"design_size": self.trace.design_size, "start_kept": self.trace.kept_start,
                  "line_restart": self.trace.line_restart, "global_search": self.trace.global_search,
                  "global_search_kept": self.trace.global_kept}
            if self.trace.lag_train_rms is not None:
                d["servo_lag_train_rms_deg"] = list(self.trace.lag_train_rms)
        if self.excitation is not None:
            d["excitation"] = self.excitation.to_dict()
        if self.uncertainty is not None:
            d["uncertainty"] = self.uncertainty.to_dict()
        return d
