"""``warpbridge review LOG [CYCLELOG] -o REPORT.html``: a flight reviewed from the FC's log and the bridge's.

LOG is the flight controller's log (ArduPilot ``.BIN``, PX4 ``.ulg``, a ground station's ``.tlog``);
CYCLELOG the bridge's cycle log of the same flight. With both, the cycle log (the loop's rate) is put
on the FC's clock (``logjoin``) and the FC's log gives the aileron output, roll rate, airspeed and
events; with LOG alone, the bridge's named values as the FC logged them stand in for the cycle log, at
their telemetry rate. The report (one HTML file with its figures inside, and a JSON summary beside it)
shows per wing the aileron command, warp setpoint, achieved warp and error over the flight, the
hysteresis loops, the tracking error by airspeed band and by phase (loading, unloading, after a
reversal, holding), the FC's and the bridge's events, the link's latency and lost messages, and the
roll authority: roll rate against differential warp per airspeed band with a fitted gain, and the
feed-forward of the FC's roll-rate controller it implies.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from warpbridge.bridge.commands.fclog import (
    MAX_CHANNELS,
    FcEvent,
    FcLog,
    Series,
    check_readable,
    read_fc_log,
    roll_surface,
)
from warpbridge.bridge.commands.logfile import write_text_atomic
from warpbridge.bridge.commands.logjoin import (
    WINGS,
    Alignment,
    CycleLog,
    aileron_series,
    align,
    join_mismatch,
    join_unchecked,
    read_cycle_log,
)
from warpbridge.bridge.errors import UserError

log = logging.getLogger(__name__)

TAG = {"left": "L", "right": "R"}
DIAGNOSE_MIN_HZ = 50.0  # below this a log locates a gap but cannot tell delay, rate limit and sensor lag apart
MIN_AIRBORNE_MS = 6.0  # samples below this airspeed are left out of the roll-authority fit
REVERSAL_WINDOW_S = 0.5  # "after reversal": this long after the setpoint turns
HOLD_RATE_DEG_S = 0.5  # |d setpoint / dt| below this: holding
RATE_HALF_WINDOW_S = 0.05  # the setpoint's rate is taken over twice this
BAND_WIDTH_MS = 3.0
MIN_BAND_SAMPLES = 30
LAG_GRID_S = np.arange(0.0, 0.42, 0.02)  # roll rate follows the warp after this much at most
PHASES = ("loading", "unloading", "after reversal", "holding")
MIN_FIT_R2 = 0.5  # a band's fit explains less than this: too few or too small manoeuvres, no FF implied
PWM_RANGE_US = (500.0, 2500.0)  # a plausible servo output trim, us
MAX_HALF_RANGE_US = 1000.0
CUT_NOTE_S = 1.0  # a cycle log longer than the FC's log by more than this is said to be cut


# ------------------------------------------------------------------------------------------------ data


@dataclass
class WingTrack:
    """One wing over the flight (deg, mm)."""

    setpoint: np.ndarray
    warp: np.ndarray  # NaN without a sensor
    u: np.ndarray

    @property
    def error(self) -> np.ndarray:
        return self.warp - self.setpoint

    @property
    def measured(self) -> bool:
        return bool(np.isfinite(self.warp).sum() > 10)


@dataclass
class Flight:
    """The joined flight on one time base (s, FC clock)."""

    source: str  # "cycle log" or "FC log named values"
    t: np.ndarray
    rate_hz: float
    wings: dict[str, WingTrack]
    airspeed: np.ndarray
    aileron: np.ndarray  # the FC's aileron output, us (NaN where not logged)
    aileron_channel: int | None
    roll_rate: np.ndarray  # deg/s
    events: list[FcEvent]
    latency_ms: np.ndarray  # age of the servo output the bridge used
    notes: list[str] = field(default_factory=list)  # what the join left out

    def differential(self) -> tuple[np.ndarray, bool]:
        """Left minus right warp: measured where both wings have a sensor, else the setpoints."""
        left, right = self.wings["left"], self.wings["right"]
        if left.measured and right.measured:
            return left.warp - right.warp, True
        return left.setpoint - right.setpoint, False


@dataclass
class ErrorStat:
    label: str
    n: int
    rms: float
    mean: float
    p95: float


@dataclass
class GainFit:
    """Roll rate (deg/s) = gain * differential warp (deg) + bias, in one airspeed band."""

    band: str
    lo_ms: float
    hi_ms: float
    n: int
    gain: float  # deg/s per deg of differential warp
    bias: float
    r2: float
    output_gain: float  # deg/s per unit of the FC's aileron output (-1..1)
    ff_ardupilot: float  # RLL_RATE_FF that gives this rate from the output at the band's airspeed
    reliable: bool  # n >= MIN_BAND_SAMPLES and R2 >= MIN_FIT_R2: the band's manoeuvres support the fit
    output_r2: float = math.nan  # R2 of the fit of the roll rate to the FC's output
    output_n: int = 0  # samples of that fit
    no_ff: str = ""  # why no feed-forward is implied from the output gain ("" when it is)


@dataclass
class LinkStats:
    latency_source: str
    latency_median_ms: float
    latency_p95_ms: float
    latency_max_ms: float
    servo_messages: int
    servo_lost: int
    named_expected: dict[str, int] = field(default_factory=dict)
    named_received: dict[str, int] = field(default_factory=dict)
    tlog_loss: dict[str, tuple[int, int]] = field(default_factory=dict)


@dataclass
class Review:
    """Everything the report shows, and the JSON summary."""

    fc_log: str
    cycle_log: str | None
    fc_format: str
    autopilot: str
    source: str
    rate_hz: float
    duration_s: float
    alignment: dict | None
    tracking: dict[str, dict[str, list[ErrorStat]]]
    roll_authority: list[GainFit]
    roll_lag_s: float
    roll_uses_measured_warp: bool
    fc_roll_ff: float  # the FC's RLL_RATE_FF in the log's parameters (NaN when absent: PX4, a tlog without them)
    link: LinkStats
    events: list[FcEvent]
    warnings: list[str]
    notes: list[str]


# ------------------------------------------------------------------------------------------------ joining


def _events_from_modes(t: np.ndarray, modes: np.ndarray) -> list[FcEvent]:
    out = []
    change = np.flatnonzero(np.r_[True, modes[1:] != modes[:-1]])
    for i in change:
        kind = "failsafe" if "failsafe" in str(modes[i]) else "bridge"
        out.append(FcEvent(float(t[i]), kind, f"bridge {modes[i]}"))
    return out


MODE_NAMES = {0.0: "open", 1.0: "pi", 2.0: "ff", 3.0: "ff+pi", -1.0: "failsafe"}


def flight_from_cycle_log(cl: CycleLog, fc: FcLog, al: Alignment, channel: int | None = None) -> Flight:
    """The cycle log's rows on the FC's clock, over the span the FC logged (ArduPilot starts its log at
    arming by default: the bridge's rows before it have nothing to be joined to)."""
    t = al.fc_time(cl.t)
    f0, f1 = fc.span
    keep = (t >= f0) & (t <= f1)
    if keep.sum() < 10:
        raise UserError(f"the cycle log ({cl.t.size} rows) does not overlap the FC's log ({f0:.0f}..{f1:.0f} s on "
                        "the FC's clock): logs of different flights?")
    notes = []
    total, kept = float(cl.t[-1] - cl.t[0]), float(t[keep][-1] - t[keep][0])
    if total - kept > CUT_NOTE_S:
        notes.append(f"the FC's log covers {kept:.0f} s of the cycle log's {total:.0f} s: the review keeps those")
    t = t[keep]
    wings = {w: WingTrack(cl.wing[w]["setpoint"][keep], cl.wing[w]["warp"][keep], cl.wing[w]["u"][keep])
             for w in WINGS}
    ail = aileron_series(fc, channel)
    gap = 0.5
    aspd = cl.airspeed[keep]
    airspeed = aspd if np.isfinite(aspd).any() else _at(fc.airspeed, t, 2.0)
    latency = np.full(t.size, np.nan) if cl.fc_t is None else 1e3 * (t - cl.fc_t[keep])
    events = list(fc.events) + _events_from_modes(t, cl.mode[keep])
    return Flight("cycle log", t, cl.rate_hz, wings, airspeed, _at(ail[1] if ail else None, t, gap),
                  ail[0] if ail else None, _at(fc.roll_rate, t, gap), sorted(events, key=lambda e: e.t), latency,
                  notes)


def _at(s: Series | None, t: np.ndarray, max_gap: float) -> np.ndarray:
    return np.full(t.size, np.nan) if s is None else s.at(t, max_gap)


def flight_from_fc_log(fc: FcLog, channel: int | None = None) -> Flight:
    base = fc.named.get("L_sp") or fc.named.get("L_cmd") or fc.named.get("R_sp")
    if base is None or len(base) < 10:
        raise UserError(f"{fc.path}: the bridge's named values (L_sp, R_sp, ...) are not in this log; give the "
                        "cycle log too (warpbridge review LOG CYCLELOG)" + (f" ({fc.notes[0]})" if fc.notes else ""))
    t = base.t
    gap = 3.0 / max(base.rate_hz, 0.1)

    def named(name: str) -> np.ndarray:
        return _at(fc.named.get(name), t, gap)

    wings = {w: WingTrack(named(f"{TAG[w]}_sp"), named(f"{TAG[w]}_warp"), named(f"{TAG[w]}_cmd")) for w in WINGS}
    airspeed = named("WB_aspd")
    if not np.isfinite(airspeed).any():
        airspeed = _at(fc.airspeed, t, 2.0)
    ail = aileron_series(fc, channel)
    events = list(fc.events)
    mode = fc.named.get("WB_mode")
    if mode is not None and len(mode):
        events += _events_from_modes(mode.t, np.array([MODE_NAMES.get(float(v), f"{v:g}") for v in mode.v]))
    return Flight("FC log named values", t, base.rate_hz, wings, airspeed, _at(ail[1] if ail else None, t, 0.5),
                  ail[0] if ail else None, _at(fc.roll_rate, t, 0.5), sorted(events, key=lambda e: e.t),
                  named("WB_lat"))


# ------------------------------------------------------------------------------------------------ analysis


def _stat(label: str, e: np.ndarray) -> ErrorStat:
    e = e[np.isfinite(e)]
    if e.size == 0:
        return ErrorStat(label, 0, math.nan, math.nan, math.nan)
    return ErrorStat(label, int(e.size), float(np.sqrt(np.mean(e * e))), float(e.mean()),
                     float(np.percentile(np.abs(e), 95)))


def phases(t: np.ndarray, setpoint: np.ndarray) -> np.ndarray:
    """Per sample: the phase of the setpoint (index into ``PHASES``; -1 where unknown).

    Loading: the setpoint rises (the tendon pulls); unloading: it falls; after reversal: within
    ``REVERSAL_WINDOW_S`` of a change between the two; holding: it moves slower than ``HOLD_RATE_DEG_S``."""
    out = np.full(t.size, -1)
    ok = np.isfinite(setpoint)
    if ok.sum() < 3:
        return out
    # the rate over +-RATE_HALF_WINDOW_S: the setpoint is a staircase (held between the FC's messages), whose
    # sample-to-sample gradient is zero between steps
    tt, ss = t[ok], setpoint[ok]
    h = RATE_HALF_WINDOW_S
    rate = (np.interp(t + h, tt, ss) - np.interp(t - h, tt, ss)) / (2 * h)
    moving = np.abs(rate) >= HOLD_RATE_DEG_S
    out[:] = 3
    out[moving & (rate > 0)] = 0
    out[moving & (rate < 0)] = 1
    direction = np.sign(rate) * moving
    last_dir, turned_at = 0.0, -math.inf
    for i in np.flatnonzero(moving):
        if last_dir and direction[i] != last_dir:
            turned_at = t[i]
        last_dir = direction[i]
        if t[i] - turned_at <= REVERSAL_WINDOW_S:
            out[i] = 2
    out[~ok] = -1
    return out


def airspeed_bands(airspeed: np.ndarray, edges: list[float] | None = None) -> list[tuple[float, float]]:
    """Airspeed bands: ``edges`` given, else ``BAND_WIDTH_MS`` wide over the airborne samples."""
    a = airspeed[np.isfinite(airspeed) & (airspeed >= MIN_AIRBORNE_MS)]
    if edges:
        e = sorted(edges)
        return list(zip(e[:-1], e[1:], strict=False))
    if a.size < MIN_BAND_SAMPLES:
        return []
    lo = BAND_WIDTH_MS * math.floor(np.percentile(a, 1) / BAND_WIDTH_MS)
    hi = BAND_WIDTH_MS * math.ceil(np.percentile(a, 99) / BAND_WIDTH_MS + 1e-9)
    e = list(np.arange(lo, hi + 1e-9, BAND_WIDTH_MS))
    bands = []
    for a0, a1 in zip(e[:-1], e[1:], strict=False):
        n = int(((a >= a0) & (a < a1)).sum())
        if n >= MIN_BAND_SAMPLES:
            bands.append((float(a0), float(a1)))
    return bands


def tracking(f: Flight, bands: list[tuple[float, float]]) -> dict[str, dict[str, list[ErrorStat]]]:
    out = {}
    for w, wt in f.wings.items():
        e = wt.error
        ph = phases(f.t, wt.setpoint)
        by_band = [_stat(f"{a0:g}-{a1:g} m/s", e[(f.airspeed >= a0) & (f.airspeed < a1)]) for a0, a1 in bands]
        by_phase = [_stat(name, e[ph == k]) for k, name in enumerate(PHASES)]
        out[w] = {"all": [_stat("whole flight", e)], "airspeed": by_band, "phase": by_phase}
    return out


def _lagged(t: np.ndarray, x: np.ndarray, lag: float) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return np.full(t.size, np.nan)
    return np.interp(t + lag, t[ok], x[ok], left=np.nan, right=np.nan)


def _fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least squares y = k x + c: (k, c, R^2); NaNs below ``MIN_BAND_SAMPLES`` samples."""
    if x.size < MIN_BAND_SAMPLES or np.ptp(x) <= 0:
        return math.nan, math.nan, math.nan
    k, c = np.polyfit(x, y, 1)
    res = y - (k * x + c)
    ss = float(np.sum((y - y.mean()) ** 2))
    return float(k), float(c), float(1 - np.sum(res * res) / ss) if ss > 0 else math.nan


def roll_authority(f: Flight, bands: list[tuple[float, float]], trim_us: float, half_range_us: float,
                   scaling_speed: float) -> tuple[list[GainFit], float]:
    """Per airspeed band the roll-rate gain of the differential warp (and of the FC's output), at the lag
    (0..0.4 s) where the roll rate follows the warp best over the whole flight."""
    delta, _ = f.differential()
    air = np.isfinite(f.airspeed) & (f.airspeed >= MIN_AIRBORNE_MS)
    best, best_lag = -1.0, 0.0
    for lag in LAG_GRID_S:
        p = _lagged(f.t, f.roll_rate, lag)
        ok = air & np.isfinite(p) & np.isfinite(delta)
        if ok.sum() > MIN_BAND_SAMPLES and np.ptp(delta[ok]) > 0 and np.std(p[ok]) > 0:
            r = abs(float(np.corrcoef(delta[ok], p[ok])[0, 1]))
            if r > best:
                best, best_lag = r, float(lag)
    p = _lagged(f.t, f.roll_rate, best_lag)
    a = (f.aileron - trim_us) / half_range_us
    mixer = _mixer_sign(delta[air], a[air])
    fits = []
    for a0, a1 in bands:
        sel = air & (f.airspeed >= a0) & (f.airspeed < a1) & np.isfinite(p) & np.isfinite(delta)
        k, c, r2 = _fit(delta[sel], p[sel])
        sel_a = sel & np.isfinite(a)
        ka, _, r2a = _fit(a[sel_a], p[sel_a])
        v = float(np.mean(f.airspeed[sel])) if sel.any() else 0.5 * (a0 + a1)
        reliable = bool(sel.sum() >= MIN_BAND_SAMPLES and math.isfinite(r2) and r2 >= MIN_FIT_R2)
        no_ff = _why_no_ff(k, reliable, ka, r2a, int(sel_a.sum()), mixer)
        # ArduPlane's roll-rate FF: output (deg of a 45 deg full throw) = rate * FF * SCALING_SPEED / airspeed;
        # the output gain's sign agrees with the warp gain's (a reversed servo makes both negative)
        ff = 45.0 * v / (abs(ka) * scaling_speed) if not no_ff else math.nan
        fits.append(GainFit(f"{a0:g}-{a1:g} m/s", a0, a1, int(sel.sum()), k, c, r2, ka, ff, reliable, r2a,
                            int(sel_a.sum()), no_ff))
    return fits, best_lag


def _mixer_sign(delta: np.ndarray, a: np.ndarray) -> float:
    """+1 when the differential warp rises with the FC's output (the bridge's mixer), -1 when it falls, 0 when
    the flight does not say."""
    ok = np.isfinite(delta) & np.isfinite(a)
    if ok.sum() < MIN_BAND_SAMPLES or np.ptp(delta[ok]) <= 0 or np.ptp(a[ok]) <= 0:
        return 0.0
    return float(np.sign(np.corrcoef(a[ok], delta[ok])[0, 1]))


def _why_no_ff(k: float, reliable: bool, ka: float, r2a: float, n_out: int, mixer: float) -> str:
    """Why no feed-forward is implied from a band's output gain ``ka`` ("" when one is)."""
    if not reliable:
        return "the warp gain's fit is unreliable"
    if n_out < MIN_BAND_SAMPLES:
        return "too few samples of the FC's aileron output in this band"
    if not math.isfinite(ka):
        return "the FC's aileron output does not move in this band"
    if not (math.isfinite(r2a) and r2a >= MIN_FIT_R2):
        return f"the output gain's fit is unreliable (R2 {r2a:.2f} < {MIN_FIT_R2:g})"
    expected = np.sign(k) * (mixer or 1.0)
    if ka == 0 or np.sign(ka) != expected:
        return ("the output gain's sign disagrees with the warp gain's (the roll rate follows the warp one way and "
                "the FC's output the other): check the aileron channel and its reversal")
    return ""


def _lost(stamps: np.ndarray) -> tuple[int, int]:
    """(messages, messages lost) from the times of the messages that arrived."""
    s = np.unique(stamps[np.isfinite(stamps)])
    if s.size < 3:
        return int(s.size), 0
    d = np.diff(s)
    nominal = float(np.median(d))
    if nominal <= 0:
        return int(s.size), 0
    return int(s.size), int(np.sum(np.maximum(0, np.round(d / nominal) - 1)))


def link_stats(f: Flight, fc: FcLog, cl: CycleLog | None) -> LinkStats:
    lat = f.latency_ms[np.isfinite(f.latency_ms)]
    src = "cycle log: FC time at use minus the servo message's stamp" if f.source == "cycle log" else "WB_lat"
    q = (lambda p: float(np.percentile(lat, p))) if lat.size else (lambda p: math.nan)
    n, lost = _lost(cl.fc_t) if cl is not None and cl.fc_t is not None else (0, 0)
    expected, received = {}, {}
    for name, s in sorted(fc.named.items()):
        got, missed = _lost(s.t)
        received[name], expected[name] = len(s), got + missed
    return LinkStats(src, q(50), q(95), float(lat.max()) if lat.size else math.nan, n, lost, expected, received,
                     dict(fc.link_loss))


FORMAT_NAMES = {"ulog": "PX4 ULog", "dataflash": "DataFlash", "tlog": "tlog"}


def check_vehicle_and_channel(fc: FcLog, channel: int | None) -> list[str]:
    """The warnings of the vehicle's type and the aileron's output; a UserError for a vehicle without a wing
    (unless ``channel`` names the output to review), or a ``channel`` this log cannot carry or did not log."""
    warnings = []
    if channel is not None:
        if not 1 <= channel <= fc.max_channel:
            raise UserError(f"--channel {channel}: {FORMAT_NAMES.get(fc.fmt, fc.fmt)} logs carry outputs 1 to "
                            f"{fc.max_channel}")
        if fc.outputs_t.size and fc.output(channel) is None:
            logged = [ch for ch in range(1, fc.outputs.shape[1] + 1) if fc.output(ch) is not None]
            raise UserError(f"--channel {channel}: output {channel} is not in this log (outputs logged: "
                            f"{', '.join(map(str, logged)) or 'none'})")
        if (s := fc.output(channel)) is not None and np.ptp(s.v) == 0:
            warnings.append(f"output {channel} (--channel) holds {s.v[0]:.0f} us over the whole log: is it the "
                            "aileron?")
    if fc.wingless:
        said = f"the log's vehicle is a {fc.vehicle} ({fc.vehicle_source}), without a wing to warp"
        if channel is None:
            raise UserError(f"{fc.path}: {said}; give --channel N to review output N as the aileron anyway")
        warnings.append(f"{said}: output {channel} reviewed as the aileron (--channel)")
    if channel is None and (ail := aileron_series(fc)) is not None:  # the output taken when none is named
        used = ail[0]
        if used not in fc.aileron_channels:
            warnings.append(f"no aileron function in the log's parameters: guessed output {used} (use --channel)")
        elif "aileron" not in (name := roll_surface(fc, used)):
            warnings.append(f"no aileron among the FC's outputs: output {used} ({name}) is read as the aileron; "
                            "it carries roll mixed with another axis (use --channel for another output)")
    return warnings


def review(fc: FcLog, cl: CycleLog | None, *, channel: int | None = None, bands: list[float] | None = None,
           trim_us: float = 1500.0, half_range_us: float = 400.0) -> tuple[Review, Flight, Alignment | None]:
    """Analyse a flight: join, tracking, roll authority, link; no files written."""
    warnings = check_vehicle_and_channel(fc, channel)
    notes = list(fc.notes)
    al = None
    if cl is not None:
        al = align(cl, fc, channel)
        flight = flight_from_cycle_log(cl, fc, al, channel)
        notes += al.notes
        warnings += flight.notes
        if (unchecked := join_unchecked(al)) is not None:
            warnings.append(unchecked)
        if (mismatch := join_mismatch(al)) is not None:
            warnings.append(mismatch)
    else:
        flight = flight_from_fc_log(fc, channel)
    if flight.rate_hz < DIAGNOSE_MIN_HZ:
        warnings.append(
            f"the bridge's values come at {flight.rate_hz:.1f} Hz ({flight.source}): enough to locate where "
            "tracking degrades (time, airspeed, phase), too low to tell delay, rate limit and sensor lag apart "
            "(warpbridge diagnose needs the cycle log's rate); give the cycle log, or raise WB_TLM_HZ "
            "(docs/review.md)")
    if not any(wt.measured for wt in flight.wings.values()):
        warnings.append("no warp measured (no sensor): achieved warp and tracking error are not available; "
                        "roll authority uses the commanded differential warp")
    if not np.isfinite(flight.roll_rate).any():
        warnings.append("no roll rate in the FC log: no roll authority")
    band_list = airspeed_bands(flight.airspeed, bands)
    if not band_list:
        warnings.append(f"too few airborne samples (airspeed >= {MIN_AIRBORNE_MS:g} m/s) for airspeed bands")
    scaling = float(fc.params.get("SCALING_SPEED", 15.0))
    fits, lag = roll_authority(flight, band_list, trim_us, half_range_us, scaling)
    rr = fc.roll_rate.rate_hz if fc.roll_rate is not None else 0.0
    if fits and rr and rr < 10:
        warnings.append(f"roll rate logged at {rr:.1f} Hz: the roll-authority fit is coarse")
    span = float(flight.t[-1] - flight.t[0]) if flight.t.size else 0.0
    rv = Review(fc_log=fc.path, cycle_log=cl.path if cl else None, fc_format=fc.fmt, autopilot=fc.autopilot,
                source=flight.source, rate_hz=flight.rate_hz, duration_s=span,
                alignment=None if al is None else {**asdict(al), "residual_s": al.residual_s},
                tracking=tracking(flight, band_list), roll_authority=fits, roll_lag_s=lag,
                roll_uses_measured_warp=flight.differential()[1],
                fc_roll_ff=float(fc.params.get("RLL_RATE_FF", math.nan)), link=link_stats(flight, fc, cl),
                events=[e for e in flight.events if flight.t[0] - 1 <= e.t <= flight.t[-1] + 1] if span else [],
                warnings=warnings, notes=notes)
    for w in warnings:
        log.warning("%s", w)
    return rv, flight, al


# ------------------------------------------------------------------------------------------------ output


def _clean(x):
    """JSON-safe: NaN and infinities become null, numpy scalars plain numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def summary_json(rv: Review) -> str:
    d = asdict(rv)
    d["format"] = "warpbridge-review/1"
    return json.dumps(_clean(d), indent=1)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="the flight controller's log: ArduPilot .BIN, PX4 .ulg or a ground station's .tlog")
    p.add_argument("cyclelog", nargs="?", help="the bridge's cycle log of the same flight (CSV)")
    p.add_argument("-o", "--output", help="REPORT.html to write (default: LOG's name with -review.html); the "
                                          "JSON summary goes beside it (.json)")
    p.add_argument("--channel", type=int,
                   help="the FC output carrying the aileron, 1 to 32 (a PX4 .ulg: 16) (default: from its parameters); "
                        "needed to review a log whose vehicle has no wing")
    p.add_argument("--bands", help="airspeed band edges, m/s, e.g. 10,14,18,22 (default: 3 m/s bands)")
    p.add_argument("--trim", type=float, default=1500.0, help="aileron output trim, us, 500 to 2500 (default 1500)")
    p.add_argument("--half-range", type=float, default=400.0,
                   help="aileron output from trim to full deflection, us, above 0 to 1000 (default 400)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


@contextlib.contextmanager
def _progress(quiet: bool) -> Iterator[Callable[[int, int], None] | None]:
    """A progress bar for reading the FC's log on a terminal (None: no bar), closed however the read ends."""
    stream = None
    if not quiet and sys.stderr is not None and sys.stderr.isatty():
        try:  # drawn on a copy of stderr's descriptor: the log reader silences the descriptor while it reads
            stream = os.fdopen(os.dup(sys.stderr.fileno()), "w")
        except (OSError, ValueError, io.UnsupportedOperation):
            stream = None
    if stream is None:
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=100, unit="%", desc="reading", leave=False, file=stream)

    def update(done: int, total: int) -> None:
        bar.n = int(100 * done / max(total, 1))
        bar.refresh()
        if done >= total:  # cleared before anything the reader logs after its last step
            bar.close()

    try:
        yield update
    finally:
        bar.close()
        stream.close()


def fmt_number(x: float | None, digits: int = 3) -> str:
    """``x`` to ``digits`` decimals, a zero never signed ("-0.00" is "0.00"); "-" for None and NaN."""
    if x is None or not math.isfinite(x):
        return "-"
    return f"{round(x, digits) + 0.0:.{digits}f}"


def parse_bands(text: str | None) -> list[float] | None:
    """``--bands``: at least two distinct finite edges, m/s, not negative (sorted)."""
    if not text:
        return None
    try:
        edges = [float(x) for x in text.split(",")]
    except ValueError:
        raise UserError(f"--bands: not a list of numbers ({text!r})") from None
    if len(edges) < 2:
        raise UserError("--bands: give at least two edges")
    if not all(math.isfinite(e) for e in edges):
        raise UserError(f"--bands: edges must be finite numbers ({text!r})")
    if any(e < 0 for e in edges):
        raise UserError(f"--bands: airspeeds cannot be negative ({text!r})")
    edges = sorted(edges)
    if any(b <= a for a, b in zip(edges[:-1], edges[1:], strict=False)):
        raise UserError(f"--bands: an edge is given twice ({text!r})")
    return edges


def check_options(args: argparse.Namespace) -> Path:
    """Refuse options that cannot be right before any log is read; the report's path."""
    if args.channel is not None and not 1 <= args.channel <= MAX_CHANNELS:
        raise UserError(f"--channel {args.channel}: outputs are numbered 1 to {MAX_CHANNELS} (ArduPilot's "
                        "SERVO1..32; a PX4 .ulg 1 to 16)")
    if not math.isfinite(args.trim) or not PWM_RANGE_US[0] <= args.trim <= PWM_RANGE_US[1]:
        raise UserError(f"--trim {args.trim:g}: give the aileron output's trim in us, {PWM_RANGE_US[0]:.0f} to "
                        f"{PWM_RANGE_US[1]:.0f}")
    if not math.isfinite(args.half_range) or not 0 < args.half_range <= MAX_HALF_RANGE_US:
        raise UserError(f"--half-range {args.half_range:g}: give the output's travel from trim to full "
                        f"deflection in us, above 0 and at most {MAX_HALF_RANGE_US:.0f}")
    check_readable(args.log, "FC log")
    if args.cyclelog:
        check_readable(args.cyclelog, "cycle log")
    out = Path(args.output) if args.output else Path(args.log).with_name(Path(args.log).stem + "-review.html")
    if args.output and (out.is_dir() or args.output.endswith(("/", "\\"))):
        raise UserError(f"-o {args.output}: is a directory; give the report's file name (REPORT.html)")
    if out.suffix.lower() == ".json":
        raise UserError(f"-o {args.output}: give the HTML report's name (REPORT.html); the JSON summary is written "
                        "beside it")
    if not out.parent.is_dir():
        raise UserError(f"{out}: directory {out.parent} does not exist")
    inputs = {Path(args.log).resolve()} | ({Path(args.cyclelog).resolve()} if args.cyclelog else set())
    if {out.resolve(), out.with_suffix(".json").resolve()} & inputs:
        raise UserError(f"-o {out}: the report or its JSON summary would overwrite an input log")
    return out


def _join_line(al: Alignment) -> str:
    """The printed line of the join."""
    line = f"join: {al.method}, offset {al.offset_s:.3f} s"
    if not math.isfinite(al.check_lag_s):
        return line + ", not checked"
    line += f", check lag {fmt_number(al.check_lag_s * 1e3, 1)} ms (|r| {al.check_corr:.3f})"
    if math.isfinite(al.residual_s):
        return line + f", residual {fmt_number(al.residual_s * 1e3, 1)} ms"
    return line + ", residual none (placed by cross-correlation)"


def _roll_line(g: GainFit, px4: bool) -> str:
    """The printed line of one band's roll authority."""
    below = (f" (the fit leaves out samples below {MIN_AIRBORNE_MS:g} m/s, not airborne)"
             if g.lo_ms < MIN_AIRBORNE_MS else "")
    if g.n == 0:
        return f"roll authority {g.band}: no samples in this band{below}"
    fit = (f"{fmt_number(g.gain, 2)} deg/s per deg (R2 {fmt_number(g.r2, 2)}, n {g.n})" if math.isfinite(g.gain)
           else f"n {g.n}")
    if g.n < MIN_BAND_SAMPLES:
        return f"roll authority {g.band}: {fit}, too few samples to fit (fewer than {MIN_BAND_SAMPLES}){below}"
    if not g.reliable:
        return f"roll authority {g.band}: {fit}, too little manoeuvring to fit{below}"
    out = (f"{fmt_number(g.output_gain, 0)} deg/s per full output (R2 {fmt_number(g.output_r2, 2)})"
           if math.isfinite(g.output_gain) else "")
    if g.no_ff:
        said = f"{out}; " if out else ""
        return f"roll authority {g.band}: {fit}, {said}no {'FF' if px4 else 'RLL_RATE_FF'}: {g.no_ff}{below}"
    if px4:  # FW_RR_FF: docs/review.md
        return f"roll authority {g.band}: {fit}, {out}{below}"
    return f"roll authority {g.band}: {fit}, RLL_RATE_FF ~ {g.ff_ardupilot:.3f} from {out}{below}"


def main(args: argparse.Namespace) -> int:
    from warpbridge.bridge.commands.review_plots import write_html

    t0 = time.perf_counter()
    out = check_options(args)
    bands = parse_bands(args.bands)
    log.info("reading %s", args.log)
    with _progress(args.no_progress) as progress:
        fc = read_fc_log(args.log, progress=progress)
    f0, f1 = fc.span
    log.info("read %.0f s of flight from %s in %.1f s", f1 - f0, args.log, time.perf_counter() - t0)
    cl = read_cycle_log(args.cyclelog) if args.cyclelog else None
    rv, flight, al = review(fc, cl, channel=args.channel, bands=bands, trim_us=args.trim,
                            half_range_us=args.half_range)
    t_read = time.perf_counter() - t0
    log.info("joined and analysed in %.1f s; drawing the report", t_read)
    write_html(out, rv, flight, fc, cl, al)
    js = out.with_suffix(".json")
    write_text_atomic(js, summary_json(rv) + "\n")
    print(f"review: {rv.duration_s:.0f} s of flight from {rv.source} at {rv.rate_hz:.0f} Hz "
          f"({fc.fmt}{' + cycle log' if cl else ''}); read and joined in {t_read:.1f} s, "
          f"report in {time.perf_counter() - t0:.1f} s")
    if al is not None:
        print(_join_line(al))
    for w in WINGS:
        s = rv.tracking[w]["all"][0]
        if s.n:
            print(f"{w} wing: tracking RMS {s.rms:.3f} deg, 95% {s.p95:.3f} deg over {s.n} samples")
    for g in rv.roll_authority:
        print(_roll_line(g, fc.autopilot == "px4"))
    for w in rv.warnings:
        print(f"note: {w}")
    print(f"wrote {out} and {js}")
    return 0
