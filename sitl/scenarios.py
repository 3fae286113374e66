"""Named SITL scenarios: the FC's aileron PWM over time, and the air the wings fly in.

A scenario is flown on a ``Rig``: the SITL airframe (one shared aileron output,
1100/1500/1900 us, the right wing reversed; each wing pre-warped to 6 deg with
12 deg at full aileron, so both move both ways) and the wiring of the servo
board (tendon servos on Maestro channels 0/1, flex sensors on inputs 2/3).
``Rig.config_toml`` writes the bridge configuration for that rig, used by the
real-time run and parsed by the lock-step run alike.

Scenarios (``SCENARIOS``): ``random`` (the paper's bench reference: random roll
low-passed at 1 Hz, scaled so each wing's warp setpoint swings 4 deg about its
bias), ``steps``, ``doublet``, ``sweep`` (0.5 -> 3 Hz, the paper's sine range),
and ``gust7`` / ``gust12`` (the random reference in the paper's gusty tunnel
flow at 7 / 12 m/s). Calm scenarios are on the bench (0 m/s), like the paper's.
``make_scenario(..., hold_s=)`` puts a neutral hold before the scenario (the
real-time run flies one, so the bridge, which holds neutral until the FC's first
message, never sees a step at start-up). ``Scenario.pwm_at(t)`` is the roll source the mock autopilot takes (a function
of time -> {channel: us}); ``Scenario.write_csv`` writes the same as
``t,ch1,airspeed``.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warpbridge.model import excitation
from warpbridge.sitl.flex_sensor import FlexSensorSpec
from warpbridge.sitl.gust import GustSpec
from warpbridge.sitl.servo_model import ServoSpec

PAPER_KP, PAPER_KI = 7.0, 1.0  # Lee et al. (2017), sec. 5.1-5.2, as printed: the paper gives no units
# Named PI gain sets (``Rig.gains``): the bridge's defaults (mm/deg, chosen for margin), and the paper's
# Kp = 7, Ki = 1 read two ways (docs/field-tuning.md, "PI gains"): as degrees of servo horn per degree of
# warp on the rig's horn, or as mm of tendon per degree.
GAIN_SETS = ("default", "paper-horn", "paper-mm")
SCENARIO_NAMES = ("random", "steps", "doublet", "sweep", "gust7", "gust12")
WINGS = ("left", "right")


@dataclass(frozen=True)
class Rig:
    """The SITL airframe and servo-board wiring (what a user would write in the config)."""

    aileron_channel: int = 1  # FC output (1-based) carrying the aileron
    pwm_min: float = 1100.0
    pwm_trim: float = 1500.0
    pwm_max: float = 1900.0
    bias_deg: float = 6.0
    max_warp_deg: float = 12.0
    servo_channels: tuple[int, int] = (0, 1)  # left, right on the Maestro
    sensor_channels: tuple[int, int] = (2, 3)
    servo: ServoSpec = field(default_factory=ServoSpec)
    sensor: FlexSensorSpec = field(default_factory=FlexSensorSpec)

    def gains(self, name: str = "default") -> tuple[float, float]:
        """A named PI gain set (``GAIN_SETS``) on this rig: (kp mm/deg, ki mm/(deg s)).

        ``default``: the bridge's defaults. ``paper-horn``: the paper's Kp = 7, Ki = 1 taken as degrees
        of servo horn per degree of warp (its dSPACE board commanded the servo), times the arc length of
        one degree on this rig's horn, ``servo.horn_mm * pi / 180`` mm (an assumption: the paper gives
        no horn radius). ``paper-mm``: the same numbers taken as mm of tendon per degree."""
        if name == "default":
            from warpbridge.bridge.config import DEFAULT_KI, DEFAULT_KP

            return DEFAULT_KP, DEFAULT_KI
        if name == "paper-horn":
            mm_per_horn_deg = self.servo.horn_mm * math.pi / 180.0
            return PAPER_KP * mm_per_horn_deg, PAPER_KI * mm_per_horn_deg
        if name == "paper-mm":
            return PAPER_KP, PAPER_KI
        raise ValueError(f"unknown gain set {name!r} (one of {', '.join(GAIN_SETS)})")

    @property
    def warp_per_aileron(self) -> float:
        """Warp (deg) per unit of normalised aileron about the bias (the smaller side)."""
        return min(self.max_warp_deg - self.bias_deg, self.bias_deg)

    def pwm_of(self, a):
        """Normalised aileron in [-1, 1] (positive = roll right, left wing gains lift) -> PWM (us)."""
        a = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)
        return np.where(a >= 0, self.pwm_trim + a * (self.pwm_max - self.pwm_trim),
                        self.pwm_trim + a * (self.pwm_trim - self.pwm_min))

    def config_toml(self, *, connection: str, servo_backend: str, sensor_backend: str, mode: str = "ff+pi",
                    kp: float | None = None, ki: float | None = None, model_file: str = "paper",
                    log: str | None = None,
                    params_file: str = "warpbridge-params.json", servo_rate_hz: float = 100.0,
                    loop_hz: float = 100.0, extra_control: dict[str, float] | None = None) -> str:
        """The bridge's TOML configuration for this rig (paths as given, relative to the file); PI gains
        left out (None) are the bridge's defaults."""
        s = self.servo
        counts, deg = self.sensor.calibration_table()
        lines = [
            "# generated by warpbridge sitl for the simulated rig",
            "[link]", f'connection = "{connection}"', f"servo_rate_hz = {servo_rate_hz:g}", "",
            "[loop]", f"rate_hz = {loop_hz:g}",
        ]
        if log:
            lines.append(f'log = "{log}"')
        lines += ["", "[telemetry]", "rate_hz = 10", "", "[params]", f'file = "{params_file}"', "",
                  "[servo]", f'backend = "{servo_backend}"', "", "[sensor]", f'backend = "{sensor_backend}"', "",
                  "[model]", f'file = "{model_file}"', ""]
        for i, wing in enumerate(WINGS):
            lines += [
                f"[wing.{wing}]", f"source_channel = {self.aileron_channel}",
                f"reverse = {'true' if wing == 'right' else 'false'}",
                f"pwm_min = {self.pwm_min:g}", f"pwm_trim = {self.pwm_trim:g}", f"pwm_max = {self.pwm_max:g}",
                f"max_warp_deg = {self.max_warp_deg:g}", f"bias_deg = {self.bias_deg:g}",
                f"servo_channel = {self.servo_channels[i]}", f"sensor_channel = {self.sensor_channels[i]}", "",
                f"[wing.{wing}.servo]", f"pulse_min_us = {s.pulse_min_us:g}", f"pulse_max_us = {s.pulse_max_us:g}",
                f"pulse_zero_us = {s.pulse_zero_us:g}", f"mm_per_us = {s.mm_per_us:.9g}", "",
                f"[wing.{wing}.sensor]", f"counts = [{', '.join(f'{c:g}' for c in counts)}]",
                f"deg = [{', '.join(f'{d:g}' for d in deg)}]", "",
                f"[wing.{wing}.control]", f'mode = "{mode}"',
            ]
            lines += [f"{k} = {v:.9g}" for k, v in (("kp", kp), ("ki", ki)) if v is not None]
            for k, v in (extra_control or {}).items():
                lines.append(f"{k} = {v:g}")
            lines.append("")
        return "\n".join(lines)


@dataclass(frozen=True)
class Scenario:
    """Roll command a(t) in [-1, 1] (sampled on a grid, interpolated) plus the flow."""

    name: str
    description: str
    duration_s: float
    rig: Rig
    grid_t: np.ndarray
    grid_a: np.ndarray
    airspeed_ms: float = 0.0
    gust: GustSpec | None = None

    def aileron(self, t):
        """Normalised aileron at time(s) t (s since the scenario started); held past the end."""
        return np.interp(t, self.grid_t, self.grid_a)

    def pwm(self, t):
        """Aileron PWM (us) at time(s) t."""
        return self.rig.pwm_of(self.aileron(t))

    def pwm_at(self, t: float) -> dict[int, float]:
        """Roll source for the mock autopilot: {FC output channel: us} at time t."""
        return {self.rig.aileron_channel: float(self.pwm(t))}

    def reference(self, t) -> dict[str, np.ndarray]:
        """Warp setpoint per wing the bridge's mixer makes of the noise-free PWM."""
        a = np.asarray(self.aileron(t), dtype=np.float64)
        r = self.rig
        out = {}
        for wing, sign in (("left", 1.0), ("right", -1.0)):
            aw = sign * a
            out[wing] = np.where(aw >= 0, r.bias_deg + aw * (r.max_warp_deg - r.bias_deg), r.bias_deg * (1 + aw))
        return out

    def write_csv(self, path: str | Path, rate_hz: float = 100.0) -> Path:
        """The roll source as ``t,ch<N>,airspeed`` rows (header), for the mock autopilot's CSV input
        (the airspeed column is the mean flow the FC's airspeed sensor reports)."""
        p = Path(path)
        n = int(math.floor(self.duration_s * rate_hz)) + 1
        t = np.arange(n) / rate_hz
        pwm = self.pwm(t)
        with p.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t", f"ch{self.rig.aileron_channel}", "airspeed"])
            for tk, pk in zip(t, pwm, strict=True):
                w.writerow([f"{tk:.4f}", f"{pk:.2f}", f"{self.airspeed_ms:g}"])
        return p


GRID_HZ = 200.0


def _grid(duration_s: float) -> np.ndarray:
    return np.arange(int(math.ceil(duration_s * GRID_HZ)) + 1) / GRID_HZ


def _random(t: np.ndarray, amp: float, seed: int) -> np.ndarray:
    a = excitation.filtered_random(t, cutoff_hz=1.0, amplitude=amp, seed=seed)
    return _ramp_in(t, a)


def _ramp_in(t: np.ndarray, a: np.ndarray, ramp_s: float = 1.0) -> np.ndarray:
    """Start from neutral: blend in over the first ``ramp_s`` (smooth), as a pilot would."""
    w = np.clip(t / ramp_s, 0.0, 1.0)
    return a * (0.5 - 0.5 * np.cos(np.pi * w))


_BUILDERS: dict[str, tuple[str, Callable[[np.ndarray, float, int], np.ndarray], float]] = {
    # name: (description, a(t, amplitude, seed), mean airspeed)
    "random": ("filtered random roll, 1 Hz cut-off, 4 deg warp amplitude (the paper's bench test)",
               _random, 0.0),
    "steps": ("roll steps 0, +, 0, -, held 2 s each", lambda t, amp, seed: excitation.steps(
        t, levels=(0.0, amp, 0.0, -amp), hold_s=2.0), 0.0),
    "doublet": ("roll doublets: + for 1 s, - for 1 s, every 4 s", lambda t, amp, seed: excitation.doublet(
        t, amplitude=amp, width_s=1.0, period_s=4.0), 0.0),
    "sweep": ("sine sweep 0.5 -> 3 Hz, 4 deg warp amplitude", lambda t, amp, seed: _ramp_in(
        t, excitation.sweep(t, 0.5, 3.0, amplitude=amp)), 0.0),
    "gust7": ("filtered random roll in the paper's gusty tunnel flow at 7 m/s", _random, 7.0),
    "gust12": ("filtered random roll in the paper's gusty tunnel flow at 12 m/s", _random, 12.0),
}


def hold_scenario(duration_s: float, *, rig: Rig | None = None) -> Scenario:
    """Neutral aileron throughout, on the bench: each wing's setpoint stays at its bias."""
    rig = rig or Rig()
    return Scenario(name="hold", description="neutral aileron (setpoint at the bias)", duration_s=float(duration_s),
                    rig=rig, grid_t=np.array([0.0, float(duration_s)]), grid_a=np.zeros(2))


def make_scenario(name: str, duration_s: float = 20.0, *, rig: Rig | None = None, seed: int = 0,
                  warp_amplitude_deg: float = 4.0, gust_intensity: float = 0.3, hold_s: float = 0.0) -> Scenario:
    """Build the named scenario; ``seed`` fixes the random reference and the gusts.

    ``hold_s``: neutral aileron for that long first, then the scenario (``duration_s`` counts both),
    so a bridge that starts following the FC during the hold sees no step."""
    if name not in _BUILDERS:
        raise ValueError(f"unknown scenario {name!r} (one of {', '.join(SCENARIO_NAMES)})")
    if not duration_s > 0:
        raise ValueError("scenario duration must be positive")
    rig = rig or Rig()
    desc, build, v = _BUILDERS[name]
    amp = warp_amplitude_deg / rig.warp_per_aileron
    if amp > 1:
        raise ValueError(f"warp amplitude {warp_amplitude_deg:g} deg exceeds the rig's range")
    if not 0.0 <= hold_s < duration_s:
        raise ValueError("the neutral hold must be shorter than the scenario")
    t = _grid(duration_s)
    if hold_s > 0:
        tb = _grid(duration_s - hold_s)
        a = np.interp(t - hold_s, tb, np.clip(build(tb, amp, seed), -1.0, 1.0), left=0.0)
    else:
        a = np.clip(build(t, amp, seed), -1.0, 1.0)
    gust = GustSpec(mean_ms=v, intensity=gust_intensity, seed=seed + 1000) if name.startswith("gust") else None
    return Scenario(name=name, description=desc, duration_s=float(duration_s), rig=rig, grid_t=t, grid_a=a,
                    airspeed_ms=v, gust=gust)
