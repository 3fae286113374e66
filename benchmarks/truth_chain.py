"""Truth side of the diagnosis benchmark: the signal path around the tendon-sheath, written from the physics.

Nothing here imports ``warpbridge.model``: the benchmark's plants must not share
a line of code with the operators the diagnosis fits. Every element sits where
it acts on a real wing and has its own dynamics:

- ``link``: the command travels through a buffered link; each sample arrives
  ``latency`` s (plus a random jitter, order kept) after it was logged and is
  held until the next one arrives (zero-order hold, not interpolation).
- ``servo``: a hobby servo's position loop, a proportional speed command capped
  at ``vmax`` mm/s, driving a motor with its own time constant ``tau_m``
  (second order, sub-stepped). A slew limit is a lower ``vmax``.
- ``linkage``: slack in the horn-to-tendon linkage, the dead-zone model of
  backlash (the tendon end is driven at ``k`` x the penetration beyond the
  slack, as a stiff contact with a damped load), sub-stepped exactly.
- ``sensor``: the warp sensor's own filter, a cascade of first-order stages
  driven by the linearly interpolated warp (first-order hold, exact); noise
  in degrees, a zero that drifts with the sensor's temperature, then ADC
  quantisation.
- ``drift``: a temperature-driven zero drift, warming with time constant
  ``tau_T`` after power-on (curved, not a ramp).

``diagnosed_*`` are the diagnosis's own effect forms, written again plainly,
for the benchmark cases that are in the model's own class.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# ---- physical elements --------------------------------------------------------------------------

@njit(cache=True)
def link(t, u, latency, jitter_u01, jitter):
    """Command delivered at each sample time: the latest sample that has arrived (ZOH), ``u[0]`` before.

    Sample j arrives at t[j] + latency + jitter * jitter_u01[j], never before its predecessor."""
    n = t.shape[0]
    out = np.empty(n)
    j = -1  # last arrived sample
    arr_prev = -1e300
    arrivals = np.empty(n)
    for i in range(n):
        a = t[i] + latency + jitter * jitter_u01[i]
        if a < arr_prev:
            a = arr_prev
        arrivals[i] = a
        arr_prev = a
    for k in range(n):
        while j + 1 < n and arrivals[j + 1] <= t[k] + 1e-12:
            j += 1
        out[k] = u[j] if j >= 0 else u[0]
    return out


@njit(cache=True)
def servo(t, c, kp, vmax, tau_m, x0, substeps):
    """Servo output (mm): speed command min(kp |c - x|, vmax) toward the command, motor lag tau_m."""
    n = t.shape[0]
    out = np.empty(n)
    x = x0
    v = 0.0
    for k in range(n):
        dt = t[k] - t[k - 1] if k > 0 else 0.0
        h = dt / substeps
        a = math.exp(-h / tau_m) if tau_m > 0 else 0.0
        for _ in range(substeps if dt > 0 else 0):
            vc = kp * (c[k] - x)
            if vc > vmax:
                vc = vmax
            elif vc < -vmax:
                vc = -vmax
            v_new = vc + (v - vc) * a
            x += 0.5 * (v + v_new) * h
            v = v_new
        out[k] = x
    return out


@njit(cache=True)
def linkage(t, x, slack, k, y0, substeps):
    """Tendon end position behind a linkage with total slack ``slack`` (mm): dy/dt = k dz(x - y)."""
    n = t.shape[0]
    out = np.empty(n)
    y = y0
    r = 0.5 * slack
    for i in range(n):
        dt = t[i] - t[i - 1] if i > 0 else 0.0
        h = dt / substeps
        a = math.exp(-k * h)
        xp = x[i - 1] if i > 0 else x[0]
        for s in range(substeps if dt > 0 else 0):
            xs = xp + (x[i] - xp) * (s + 1) / substeps
            if xs - r > y:
                y = (xs - r) + (y - (xs - r)) * a
            elif xs + r < y:
                y = (xs + r) + (y - (xs + r)) * a
        if i == 0:
            if x[0] - r > y:
                y = x[0] - r
            elif x[0] + r < y:
                y = x[0] + r
        out[i] = y
    return out


@njit(cache=True)
def first_order_foh(t, w, tau, y0):
    """First-order lag (time constant tau, s) of an input linear between samples (exact)."""
    n = t.shape[0]
    out = np.empty(n)
    y = y0
    for k in range(n):
        if k == 0 or tau <= 0:
            y = w[k] if tau <= 0 else y
            out[k] = y
            continue
        h = t[k] - t[k - 1]
        if h <= 0:
            out[k] = y
            continue
        a = math.exp(-h / tau)
        y = a * y + (1.0 - a) * w[k - 1] + (w[k] - w[k - 1]) * (1.0 - tau / h * (1.0 - a))
        out[k] = y
    return out


def sensor_filter(t: np.ndarray, w: np.ndarray, taus: tuple[float, ...]) -> np.ndarray:
    """Cascade of first-order stages (each starting settled on the first sample)."""
    y = np.ascontiguousarray(w, dtype=np.float64)
    for tau in taus:
        if tau > 0:
            y = first_order_foh(t, y, float(tau), float(y[0]))
    return y


def warming_drift(t: np.ndarray, size_deg: float, tau_T: float) -> np.ndarray:
    """Sensor zero drift of a sensor warming after power-on at t[0]: size (1 - exp(-t / tau_T))."""
    return size_deg * (1.0 - np.exp(-(t - t[0]) / tau_T))


def quantise(w: np.ndarray, step: float) -> np.ndarray:
    return np.round(w / step) * step if step > 0 else w


# ---- the diagnosis's own forms, written again (in-class cases) ------------------------------------

@njit(cache=True)
def diagnosed_delay(t, u, d):
    """u(t - d), linearly interpolated; u[0] before the log."""
    n = t.shape[0]
    out = np.empty(n)
    for k in range(n):
        tk = t[k] - d
        if tk <= t[0]:
            out[k] = u[0]
            continue
        j = np.searchsorted(t, tk) - 1
        if j >= n - 1:
            out[k] = u[n - 1]
            continue
        a = (tk - t[j]) / (t[j + 1] - t[j])
        out[k] = (1 - a) * u[j] + a * u[j + 1]
    return out


@njit(cache=True)
def diagnosed_slew(t, u, rate):
    n = t.shape[0]
    out = np.empty(n)
    y = u[0]
    for k in range(n):
        if k > 0:
            m = rate * (t[k] - t[k - 1])
            y = min(max(u[k], y - m), y + m)
        out[k] = y
    return out


@njit(cache=True)
def diagnosed_play(u, width):
    n = u.shape[0]
    out = np.empty(n)
    r = 0.5 * width
    y = u[0] - r
    for k in range(n):
        y = min(max(y, u[k] - r), u[k] + r)
        out[k] = y
    return out


def diagnosed_lag(t: np.ndarray, w: np.ndarray, tau: float) -> np.ndarray:
    """First-order lag, input held over each step (the diagnosis's discretisation)."""
    out = np.empty_like(w)
    y = float(w[0])
    a = np.exp(-np.diff(t, prepend=t[0]) / tau)
    for k in range(w.size):
        y = a[k] * y + (1.0 - a[k]) * w[k]
        out[k] = y
    return out


def dynamic_pressure_kpa(v: np.ndarray) -> np.ndarray:
    """q = rho V^2 / 2 in kPa (sea-level air, 1.225 kg/m^3)."""
    v = np.nan_to_num(np.asarray(v, dtype=np.float64))
    return 0.5 * 1.225 * v * v / 1000.0
