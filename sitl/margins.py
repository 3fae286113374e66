"""Stability margins of the warp loop: PI + servo + loop delay + the plant's small-signal slope.

Two ways, which ``benchmarks/bench_margins.py`` prints side by side:

- ``linear_response``: a linearised, sampled-data analysis. The PI as the
  controller runs it (``i += Ki e dt; u = Kp e + i``: Kp + Ki T z / (z - 1)) at
  the loop period T, a zero-order hold, the servo's first-order lag tau, an
  input delay d (sensor read to servo write, d < T) and the plant's slope k
  (deg/mm), exactly discretised:
  G(z) = k ((1 - b) z + (b - a)) / (z (z - a)),  a = exp(-T/tau), b = exp(-(T-d)/tau).
  It leaves out the servo's deadband, quantisation and slew limit and the
  extra cycles a servo message wakes.
- ``measure_loop``: a frequency-response measurement on the lock-step
  simulation: the bridge's own cycle (ticks and message wake-ups, the sensor's
  noise and ADC counts, the servo model with its deadband and slew limit)
  flying a straight-line plant of slope k (``sitl.wing.LinearPlant``) at a
  steady setpoint, with a multisine added to each servo target. With the
  command c the bridge computes and u = c + d what the servo is asked for,
  the loop is L(jw) = -C(jw) / U(jw) at each tone (least squares on the cycles).

``plant_slope`` finds k: the steepest incremental slope dw/du of a plant over the
warp range it works in, from slow sweeps of the tendon (the loop's gain is
highest there). ``margins`` reads the gain margin (1 / |L| where the phase
crosses -180 deg) and the phase margin (180 deg + the phase where |L| crosses 1)
off a frequency response; an unstable loop has a gain margin below 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Margins:
    gain: float  # gain margin (x); inf if the phase never reaches -180 deg
    phase_deg: float  # phase margin (deg); inf if |L| never crosses 1
    crossover_hz: float  # where |L| = 1 (nan if it never is)
    phase_crossover_hz: float  # where the phase is -180 deg (nan if never)

    @property
    def gain_db(self) -> float:
        return 20.0 * math.log10(self.gain) if self.gain > 0 else -math.inf

    @property
    def stable(self) -> bool:
        return self.gain > 1.0 and self.phase_deg > 0.0


def linear_response(f_hz, kp: float, ki: float, slope: float, *, loop_hz: float = 100.0, tau_s: float = 0.02,
                    delay_s: float = 0.0) -> np.ndarray:
    """Open-loop frequency response L(e^{jwT}) at ``f_hz`` (below loop_hz / 2) of the sampled PI loop."""
    T = 1.0 / loop_hz
    if not 0.0 <= delay_s < T:
        raise ValueError("the input delay must lie in [0, one loop period)")
    z = np.exp(2j * np.pi * np.asarray(f_hz, dtype=np.float64) * T)
    c = kp + ki * T * z / (z - 1.0)
    if tau_s > 0:
        a, b = math.exp(-T / tau_s), math.exp(-(T - delay_s) / tau_s)
    else:
        a, b = 0.0, 0.0
    g = slope * ((1.0 - b) * z + (b - a)) / (z * (z - a))
    return c * g


def margins(f_hz, L) -> Margins:
    """Gain and phase margins of a frequency response sampled on increasing ``f_hz``.

    The worst crossing counts where there are several; between samples log|L| and the phase are
    interpolated linearly in log f."""
    f = np.asarray(f_hz, dtype=np.float64)
    L = np.asarray(L, dtype=np.complex128)
    mag = np.log(np.abs(L))
    ph = np.unwrap(np.angle(L))
    lf = np.log(f)
    pm, fc = math.inf, math.nan
    for i in np.nonzero((mag[:-1] >= 0.0) & (mag[1:] < 0.0) | (mag[:-1] < 0.0) & (mag[1:] >= 0.0))[0]:
        s = mag[i] / (mag[i] - mag[i + 1])
        p = ph[i] + s * (ph[i + 1] - ph[i])
        m = (math.degrees(p) + 180.0) % 360.0
        m = m - 360.0 if m > 180.0 else m
        if m < pm:
            pm, fc = m, float(math.exp(lf[i] + s * (lf[i + 1] - lf[i])))
    gm, fp = math.inf, math.nan
    x = (ph + np.pi) / (2 * np.pi)  # integer where the phase is -180 deg (mod 360)
    for i in range(len(f) - 1):
        k = math.floor(max(x[i], x[i + 1]) + 1e-12)
        if min(x[i], x[i + 1]) - 1e-12 <= k <= max(x[i], x[i + 1]) + 1e-12 and x[i] != x[i + 1]:
            s = (k - x[i]) / (x[i + 1] - x[i])
            g = 1.0 / math.exp(mag[i] + s * (mag[i + 1] - mag[i]))
            if g < gm:
                gm, fp = g, float(math.exp(lf[i] + s * (lf[i + 1] - lf[i])))
        elif abs(x[i] - round(x[i])) < 1e-9:
            g = 1.0 / math.exp(mag[i])
            if g < gm:
                gm, fp = g, float(f[i])
    if abs(x[-1] - round(x[-1])) < 1e-9 and 1.0 / math.exp(mag[-1]) < gm:
        gm, fp = 1.0 / math.exp(mag[-1]), float(f[-1])
    return Margins(gm, pm, fc, fp)


def linear_margins(kp: float, ki: float, slope: float, *, loop_hz: float = 100.0, tau_s: float = 0.02,
                   delay_s: float = 0.0, points: int = 4000) -> Margins:
    """``margins`` of ``linear_response`` from 0.01 Hz up to the loop's Nyquist frequency (included)."""
    f = np.geomspace(0.01, 0.5 * loop_hz, points)
    return margins(f, linear_response(f, kp, ki, slope, loop_hz=loop_hz, tau_s=tau_s, delay_s=delay_s))


def plant_slope(plant, u_lo: float, u_hi: float, *, w_lo: float, w_hi: float, cycles: int = 3,
                step_mm: float = 0.002, span_mm: float = 0.05) -> float:
    """Steepest slope dw/du (deg/mm) of ``plant`` (a ``sitl.wing`` plant) while the warp is in
    [w_lo, w_hi]: the tendon swept slowly ``cycles`` times over [u_lo, u_hi] in ``step_mm`` steps, the
    slope taken over ``span_mm`` of travel (which averages the sensor-free warp's numerical grain)."""
    from warpbridge.sitl.wing import start_plant

    n = max(2, int(math.ceil((u_hi - u_lo) / step_mm)))
    leg = np.linspace(u_lo, u_hi, n + 1)
    u = np.concatenate([leg, leg[::-1]] * cycles)
    st = start_plant(plant, 0.0, float(u[0]))
    w = np.array([st.step(0.001 * (k + 1), float(uk), None)[0] for k, uk in enumerate(u)])
    m = max(1, int(round(span_mm / step_mm)))
    du, dw = u[m:] - u[:-m], w[m:] - w[:-m]
    mid = 0.5 * (w[m:] + w[:-m])
    ok = (np.abs(du) > 0.5 * span_mm) & (mid >= w_lo) & (mid <= w_hi)
    ok &= np.sign(u[m:] - u[m - 1:-1]) == np.sign(u[1:len(u) - m + 1] - u[:-m])  # no reversal inside the span
    if not ok.any():
        raise ValueError("the sweep never reached the warp range")
    return float(np.max(dw[ok] / du[ok]))


def multisine(freqs_hz, amplitude_mm: float):
    """Sum of tones of equal amplitude with Schroeder phases (low crest factor): d(t) in mm."""
    f = np.asarray(freqs_hz, dtype=np.float64)
    k = np.arange(1, f.size + 1)
    phases = -np.pi * k * (k - 1) / f.size

    def d(t: float) -> float:
        return float(amplitude_mm * np.sum(np.cos(2 * np.pi * f * t + phases)))

    return d


def tone_fit(t, x, freqs_hz, fitted: bool = False):
    """Complex amplitude of each tone in samples x(t) (least squares with an offset and a trend); with
    ``fitted`` also the fitted samples."""
    t = np.asarray(t, dtype=np.float64)
    cols = [np.ones_like(t), t - t.mean()]
    for f in freqs_hz:
        cols += [np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)]
    X = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(X, np.asarray(x, dtype=np.float64), rcond=None)
    c = coef[2:].reshape(-1, 2)
    amp = c[:, 0] - 1j * c[:, 1]
    return (amp, X @ coef) if fitted else amp


@dataclass(frozen=True)
class Measured:
    f_hz: np.ndarray
    L: np.ndarray  # per tone, both wings averaged
    margins: Margins
    diverged: bool  # the loop ran away (tendon at a limit or warp off by degrees): unstable
    residual: float  # RMS of the command not explained by the tones, relative to the tones' RMS


LOW_TONES = (0.5, 1.0, 2.0, 3.0, 4.5, 6.5, 9.0, 12.0, 15.0, 18.0, 21.5, 25.0, 28.5, 32.0, 36.0, 40.0, 44.0, 48.0)
HIGH_TONES = (53.0, 58.0, 64.0, 70.0, 77.0, 84.0, 91.0, 97.0)


def measure_loop(kp: float, ki: float, slope: float, *, bands=(LOW_TONES, HIGH_TONES), amplitude_mm: float = 0.03,
                 settle_s: float = 2.0, measure_s: float = 8.0, seed: int = 0, rig=None) -> Measured:
    """Frequency response of the loop on the lock-step simulation (see the module docstring): the SITL
    rig, a straight-line plant of ``slope`` deg/mm through the rig's bias warp, ff+pi at a steady
    setpoint, a multisine of ``amplitude_mm`` per tone added to the servo targets.

    Each band of tones is a run of its own: the bridge's fixed ticks sample at the loop rate, so a tone
    above half that rate shows up mirrored below it and would spoil a tone there."""
    from warpbridge.sitl.lockstep import rig_config, run_lockstep
    from warpbridge.sitl.scenarios import Rig, hold_scenario
    from warpbridge.sitl.wing import LinearPlant, WingSpec, default_plant

    rig = rig or Rig()
    bp = default_plant().params
    w0 = rig.bias_deg
    u0 = bp.a1 * w0 * w0 + bp.a2 * w0 + bp.a3  # the feed-forward's tendon at the bias, on the loading branch
    spec = WingSpec(plant=LinearPlant(slope, u0, w0))
    lo, hi = rig.servo.mm_of(rig.servo.pulse_min_us), rig.servo.mm_of(rig.servo.pulse_max_us)
    f_all, L_all, diverged, resid = [], [], False, 0.0
    for band in bands:
        freqs = np.asarray(band, dtype=np.float64)
        d = multisine(freqs, amplitude_mm)
        res, _ = run_lockstep(hold_scenario(settle_s + measure_s, rig=rig), mode="ff+pi", spec=spec,
                              config=rig_config(rig, "ff+pi", kp, ki), seed=seed,
                              inject=lambda wing, t, d=d: d(t) if t >= 0.5 else 0.0)
        keep = res.t >= settle_s
        Ls = []
        for w in res.setpoint:
            t, c = res.t[keep], res.u_cmd[w][keep]
            err = res.setpoint[w][keep] - res.warp[w][keep]
            if (np.any(~np.isfinite(c)) or np.any(c <= lo + 1e-6) or np.any(c >= hi - 1e-6)
                    or np.nanmax(np.abs(err)) > 3.0):
                diverged = True
                continue
            dd = np.array([d(x) for x in t])
            C, fit_c = tone_fit(t, c, freqs, fitted=True)
            U = tone_fit(t, c + dd, freqs)
            Ls.append(-C / U)
            resid = max(resid, float(np.std(c - fit_c) / max(np.std(fit_c - np.mean(fit_c)), 1e-12)))
        f_all.append(freqs)
        L_all.append(np.mean(Ls, axis=0) if Ls else np.full(freqs.size, np.nan + 0j))
    f = np.concatenate(f_all)
    L = np.concatenate(L_all)
    m = margins(f, L) if np.all(np.isfinite(L)) else Margins(0.0, -math.inf, math.nan, math.nan)
    if diverged:
        m = Margins(min(m.gain, 1.0), min(m.phase_deg, 0.0), m.crossover_hz, m.phase_crossover_hz)
    return Measured(f, L, m, diverged, resid)
