"""Step 1 of identification, ``read``: the log's arrays checked (``check_log``), normalised (w / Ws,
(u - uc) / Us: the search box is the same for any wing) and split; the last ``heldout_frac`` of the log (by
time) is held out and only scored. ``LogData`` carries the log through the later steps, with the servo
(``Servo``) the model's input passes through once ``servo.lag_scan`` has found one."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model.effects import servo_travel
from warpbridge.model.identification.space import BOUNDS_ONE_SIDED, BOUNDS_TWO_SIDED, Normaliser
from warpbridge.model.signals import central_range, noise_floor, reversal_indices


def check_log(t: np.ndarray, u: np.ndarray, w: np.ndarray, min_samples: int = 50) -> None:
    """Refuse data that cannot identify the model, with a reason a user can act on."""
    if t.size < min_samples:
        raise ValueError(f"log too short: {t.size} samples (need at least {min_samples})")
    if reversal_indices(u).size < 2:
        raise ValueError("the tendon input never reverses: hysteresis cannot be identified "
                         "(excite with a random or sine input)")
    if np.ptp(w) <= 0:
        raise ValueError("the measured warp never changes")
    c = np.corrcoef(u, w)[0, 1]
    if not c > 0:
        raise ValueError("warp decreases as the tendon input increases: check the sign of u or warp "
                         f"(correlation {c:.2f})")


@dataclass(frozen=True)
class Servo:
    """The servo's position loop in front of the model (``effects.servo_follow``): a first-order lag of
    ``tau_s`` capped at ``rate_mm_s`` (inf: no cap) to the edge of a dead band ``deadband_mm`` wide; the
    default passes the command through as logged."""

    tau_s: float = 0.0
    rate_mm_s: float = math.inf
    deadband_mm: float = 0.0

    @property
    def active(self) -> bool:
        return self.tau_s > 0 or math.isfinite(self.rate_mm_s) or self.deadband_mm > 0

    @property
    def parameters(self) -> int:
        """How many parameters it adds to the model (for the information criterion)."""
        return int(self.tau_s > 0) + int(math.isfinite(self.rate_mm_s)) + int(self.deadband_mm > 0)

    def apply(self, t: np.ndarray, u: np.ndarray, sent: np.ndarray | None = None) -> np.ndarray:
        """The tendon travel the servo gives for commands u (u itself when inactive); ``sent``: when each
        command reached it, s after its row (None: at the row's time)."""
        if not self.active:
            return u
        return servo_travel(t, u, self.tau_s, self.rate_mm_s, float(u[0]), self.deadband_mm, sent)

    def __str__(self) -> str:
        lag = f"{1e3 * self.tau_s:.1f} ms"
        cap = f" capped at {self.rate_mm_s:.3g} mm/s" if math.isfinite(self.rate_mm_s) else ""
        band = f", dead band {1e3 * self.deadband_mm:.0f} um" if self.deadband_mm > 0 else ""
        return lag + cap + band


@dataclass
class LogData:
    """One log ready to fit: raw and normalised arrays, the split and the noise floor."""

    t: np.ndarray
    u: np.ndarray
    w: np.ndarray
    norm: Normaliser
    u_hat: np.ndarray
    w_hat: np.ndarray
    two_sided: bool
    n_train_end: int
    split_time: float
    train_mask: np.ndarray
    held_mask: np.ndarray
    noise: float
    servo: Servo = Servo()  # the servo the model's input passes through (``lag_scan``)
    x: np.ndarray | None = field(default=None, repr=False)  # the input the model sees: u through the servo (mm)
    x_hat: np.ndarray | None = field(default=None, repr=False)  # ... normalised
    sent: np.ndarray | None = field(default=None, repr=False)  # when each command reached the servo (s after t)

    def __post_init__(self) -> None:
        if self.x is None:
            self.x, self.x_hat = self.u, self.u_hat

    def with_servo(self, servo: Servo) -> LogData:
        """The same log with the model's input passed through ``servo``."""
        x = servo.apply(self.t, self.u, self.sent)
        return replace(self, servo=servo, x=x, x_hat=(x - self.norm.uc) / self.norm.us)

    @property
    def train_duration(self) -> float:
        """The training part's length (s)."""
        n = self.n_train_end
        return float(self.t[n - 1] - self.t[0]) if n > 1 else 0.0

    @property
    def travel_span(self) -> float:
        """The command's central range (mm): what a dead band is measured against."""
        lo, hi = central_range(self.u)
        return hi - lo

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = BOUNDS_TWO_SIDED if self.two_sided else BOUNDS_ONE_SIDED
        return np.array([x[0] for x in b]), np.array([x[1] for x in b])


def read(t, u, w, heldout_frac: float, sent=None) -> LogData:
    """Step 1: the log's arrays checked, normalised and split (the last ``heldout_frac`` by time held out);
    ``sent``: when each row's command reached the servo, s after the row (None: at the row's time)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    check_log(t, u, w)
    if sent is not None:
        sent = np.ascontiguousarray(sent, dtype=np.float64)
        if sent.shape != t.shape:
            raise ValueError("sent must have one value per row")
        sent = np.where(np.isfinite(sent), np.maximum(sent, 0.0), 0.0)
    if not 0.05 <= heldout_frac <= 0.5:
        raise ValueError("heldout_frac must lie in [0.05, 0.5]")
    norm = Normaliser.from_data(u, w)
    two_sided = bool(np.mean(w < -0.05 * np.percentile(np.abs(w), 99)) > 0.02)
    n = t.size
    split_time = float(t[0] + (1.0 - heldout_frac) * (t[-1] - t[0]))
    n_end = int(np.searchsorted(t, split_time))
    train = np.zeros(n, bool)
    train[:n_end] = True
    return LogData(t, u, w, norm, (u - norm.uc) / norm.us, w / norm.ws, two_sided, n_end, split_time, train, ~train,
                   noise_floor(w), sent=sent)
