"""WingController: modes, anti-windup, bumpless switching, jitter immunity, sensor loss, tracking."""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpbridge.bridge.controller import MODES, Flags, WingController, straight_line
from warpbridge.bridge.mixer import WingMix
from warpbridge.model.boucwen import BoucWenParams, Stepper
from warpbridge.model.excitation import filtered_random

P = BoucWenParams.paper()
DT = 0.01


class ServoPlant:
    """The paper's model as the wing (forward map), behind a first-order servo lag of ``tau`` s."""

    def __init__(self, w0: float, u0: float, tau: float = 0.05) -> None:
        self.wing = Stepper(P, w0=w0)
        self.u = u0
        self.w = w0
        self.k = 1.0 - math.exp(-DT / tau)

    def step(self, u_cmd: float) -> float:
        self.u += (u_cmd - self.u) * self.k
        self.w = self.wing.forward_step(self.u)
        return self.w


def track(mode: str, ref: np.ndarray) -> float:
    c = WingController(P, mode=mode, w0=float(ref[0]))
    plant = ServoPlant(float(ref[0]), Stepper(P, w0=float(ref[0])).u)
    err = []
    for r in ref:
        cmd = c.step(float(r), plant.w, DT)
        err.append(r - plant.step(cmd.u_cmd))
    return float(np.sqrt(np.mean(np.square(err[200:]))))


def test_ff_pi_tracks_filtered_random_reference_far_better_than_open_loop():
    t = np.arange(0, 20, DT)
    ref = filtered_random(t, cutoff_hz=1.0, amplitude=4.0, offset=5.0, seed=3)
    rms_open = track("open", ref)
    rms_ffpi = track("ff+pi", ref)
    assert rms_open > 0.8  # the hysteresis is real: the straight line misses by about a degree
    assert rms_ffpi < 0.25
    assert rms_ffpi < 0.2 * rms_open


def plain_inverse(p: BoucWenParams, w_path, w0: float = 0.0, z0: float = 0.0, h: float = 1e-3) -> list[float]:
    """u (mm) at each warp of ``w_path`` (deg): the Bouc-Wen inverse model written again, plainly, for the
    tests: dz/dw = A - |z|^n (b . phi) by Heun steps of at most ``h`` deg, u = a1 w^2 + a2 w + a3 + az z."""

    def sgn(x: float) -> float:
        return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)

    def f(z: float, w_mid: float, d: float) -> float:
        b1, b2, b3, b4, b5, b6 = p.b
        sw, sz = sgn(w_mid), sgn(z)
        psi = b1 * d * sz + b2 * sw * d + b3 * sw * sz + b4 * d + b5 * sz + b6 * sw
        return p.A - abs(z) ** p.n * psi

    out, w, z = [], w0, z0
    for target in map(float, w_path):
        n = max(1, math.ceil(abs(target - w) / h))
        step = (target - w) / n
        d = sgn(step)
        for _ in range(n if step else 0):
            k1 = f(z, w + 0.5 * step, d) * step
            k2 = f(z + k1, w + 0.5 * step, d) * step
            z, w = z + 0.5 * (k1 + k2), w + step
        w = target
        out.append(p.a1 * w * w + p.a2 * w + p.a3 + p.az * z)
    return out


def test_straight_line_is_the_least_squares_line_through_the_settled_loop():
    # the loop over 0..8 deg twice from rest (z = 0), sampled at 100 warps per leg, by the plain model
    leg = np.linspace(0.0, 8.0, 100)
    path = np.concatenate([leg, leg[::-1], leg[1:], leg[::-1][1:]])
    u = plain_inverse(P, path)
    n = 2 * leg.size - 1
    slope_ref, offset_ref = np.polyfit(path[-n:], u[-n:], 1)
    slope, offset = straight_line(P, 8.0)
    assert slope == pytest.approx(slope_ref, abs=2e-4) and offset == pytest.approx(offset_ref, abs=2e-4)
    c = WingController(P, mode="open", w_max=8.0, deadband=0.0)
    cmd = c.step(4.0, None, DT)
    assert cmd.u_cmd == pytest.approx(slope_ref * 4.0 + offset_ref, abs=1e-3)
    assert cmd.mode == "open" and cmd.pi == 0.0


def test_ff_mode_is_the_inverse_model_of_the_setpoint():
    c = WingController(P, mode="ff", deadband=0.0)
    path = [0.0, 2.0, 5.0, 3.0, 6.0]
    expected = plain_inverse(P, path)
    # at rest z = 0: u = a3 = 0.7958 mm by hand; every later value from the plain integration
    assert expected[0] == pytest.approx(0.7958)
    for w, u in zip(path, expected, strict=True):
        assert c.step(w, 1.0, DT).u_cmd == pytest.approx(u, abs=1e-5)


def test_pi_only_has_no_model_and_integrates_the_error():
    c = WingController(P, mode="pi", kp=2.0, ki=1.0, deadband=0.0)
    cmd1 = c.step(4.0, 3.0, DT)
    assert cmd1.ff == 0.0
    assert cmd1.u_cmd == pytest.approx(2.0 * 1.0 + 1.0 * 1.0 * DT)
    cmd2 = c.step(4.0, 3.0, DT)
    assert cmd2.u_cmd == pytest.approx(2.0 + 2 * DT)


def test_integrator_does_not_wind_up_while_saturated():
    c = WingController(P, mode="ff+pi", kp=7.0, ki=1.0, i_max=50.0, u_min=0.0, u_max=8.0, deadband=0.0)
    for _ in range(2000):  # wing stuck far below the setpoint: command saturates high
        cmd = c.step(6.0, 0.0, DT)
    assert cmd.u_cmd == 8.0 and Flags.SATURATED in cmd.flags and Flags.I_HELD in cmd.flags
    # once the wing reaches the setpoint the command leaves the limit at once (no stored windup)
    cmd = c.step(6.0, 6.0, DT)
    assert cmd.u_cmd < 6.0
    assert abs(cmd.pi) < 1.0


def test_integrator_is_clamped_to_i_max_in_ff_pi():
    c = WingController(P, mode="ff+pi", kp=0.0, ki=10.0, i_max=0.5, u_min=-50, u_max=50, deadband=0.0)
    for _ in range(500):
        cmd = c.step(3.0, 2.0, DT)
    assert cmd.pi == pytest.approx(0.5)


@pytest.mark.parametrize("old,new", [(a, b) for a in MODES for b in MODES if a != b])
def test_mode_switch_is_bumpless(old, new):
    c = WingController(P, mode=old, kp=7.0, ki=1.0, deadband=0.0)  # a weak integrator: a step is a bump
    for k in range(200):
        cmd = c.step(4.0 + math.sin(k * DT), 3.0, DT)
    before = cmd.u_cmd
    c.set_mode(new)
    after = c.step(4.0 + math.sin(200 * DT), 3.0, DT)
    assert after.mode == new
    assert abs(after.u_cmd - before) < 0.05
    # and it settles to the new mode's own law (transfer offset decays)
    for _ in range(500):
        last = c.step(4.0, 4.0, DT)
    assert Flags.TRANSFER not in last.flags


def jitter_run(mode: str, deadband: float, mix: WingMix, jitter_us: int = 2) -> tuple[list[float], WingController,
                                                                                   ServoPlant]:
    """Hold a constant roll with +-``jitter_us`` of PWM jitter; the command over the last 500 cycles."""
    rng = np.random.default_rng(1)
    w0 = mix.warp(mix.normalise(1700))  # start settled at the constant roll
    c = WingController(P, mode=mode, w0=w0, deadband=deadband)
    plant = ServoPlant(w0, Stepper(P, w0=w0).u)
    u = []
    for k in range(1000):
        pwm = 1700 + rng.integers(-jitter_us, jitter_us + 1)
        cmd = c.step(mix.warp(mix.normalise(pwm)), plant.w, DT)
        plant.step(cmd.u_cmd)
        if k >= 500:
            u.append(cmd.u_cmd)
    return u, c, plant


MIX = WingMix(source_channel=1, reverse=False, pwm_min=1100, pwm_trim=1500, pwm_max=1900,
              max_warp_deg=10.0, bias_deg=2.0)


@pytest.mark.parametrize("mode", ["ff", "ff+pi"])
def test_jitter_deadband_from_pwm_resolution_stops_chatter_but_passes_a_step(mode):
    deadband = MIX.jitter_deadband(2.0)  # +-2 us through the wing's 0.02 deg/us
    assert deadband == pytest.approx(2.0 * 8.0 / 400.0)
    u, c, plant = jitter_run(mode, deadband, MIX)
    # mm: a tiny fraction of the ~1.5 mm hysteresis loop, and no sample-to-sample chatter
    assert max(u) - min(u) < 0.02
    assert np.max(np.abs(np.diff(u))) < 0.001
    for _ in range(100):  # a real move of 5 us (0.1 deg, just over the play) still moves it
        cmd = c.step(MIX.warp(MIX.normalise(1705)), plant.w, DT)
        plant.step(cmd.u_cmd)
    assert cmd.u_cmd - float(np.mean(u)) > 0.02


@pytest.mark.parametrize("mode", ["ff", "ff+pi"])
def test_without_the_deadband_jitter_makes_the_model_chatter(mode):
    u, _, _ = jitter_run(mode, 0.0, MIX)
    assert max(u) - min(u) > 0.1  # each tiny reversal is a jump across the hysteresis loop
    assert np.max(np.abs(np.diff(u))) > 0.05


def test_deadband_lags_a_ramp_by_at_most_its_half_width():
    c = WingController(P, mode="ff", deadband=0.04)
    for w in np.linspace(0.0, 6.0, 300):
        cmd = c.step(float(w), None, DT)
    assert cmd.u_cmd == pytest.approx(plain_inverse(P, [6.0 - 0.04])[0], abs=1e-5)  # the model saw 5.96 deg
    with pytest.raises(ValueError):
        c.set_deadband(-1.0)


def test_missing_sensor_falls_back_to_ff_with_integrator_held():
    c = WingController(P, mode="ff+pi", deadband=0.0)
    for _ in range(100):
        c.step(4.0, 3.5, DT)  # builds some integral
    held = c._i
    ref = Stepper(P)
    ref.inverse_step(4.0)
    for bad in (None, float("nan")):
        for _ in range(500):
            cmd = c.step(4.0, bad, DT)
        assert cmd.mode == "ff" and Flags.SENSOR_MISSING in cmd.flags and Flags.I_HELD in cmd.flags
        assert cmd.measured is None
        assert c._i == held
        assert cmd.u_cmd == pytest.approx(ref.u, abs=1e-3)  # transfer offset has decayed: ff only
    # the measurement returns: no jump, PI resumes
    prev = cmd.u_cmd
    cmd = c.step(4.0, 3.5, DT)
    assert cmd.mode == "ff+pi" and abs(cmd.u_cmd - prev) < 0.05


def test_output_is_clamped_to_tendon_limits():
    c = WingController(P, mode="ff", u_min=0.0, u_max=2.0)
    cmd = c.step(8.0, None, DT)
    assert cmd.u_cmd == 2.0 and Flags.SATURATED in cmd.flags


def test_live_model_change_is_bumpless():
    c = WingController(P, mode="ff", deadband=0.0)
    for _ in range(10):
        before = c.step(4.0, None, DT).u_cmd
    c.set_model(BoucWenParams(a1=P.a1, a2=P.a2 * 1.2, a3=P.a3, az=P.az, A=P.A, n=P.n, b=P.b))
    assert abs(c.step(4.0, None, DT).u_cmd - before) < 0.01


def test_unknown_mode_is_refused():
    with pytest.raises(ValueError):
        WingController(P, mode="pid")


@pytest.mark.parametrize("slack", [
    {"backlash_mm": 0.3},
    {"capstan_pull_ratio": 0.05, "capstan_release_ratio": 0.03, "capstan_zero_mm": -2.0},
])
def test_a_model_files_aero_load_and_slack_are_inverted_in_the_feed_forward(slack):
    """ff through an augmented model: the loaded, slack (backlash, or capstan stall) wing still reaches the
    setpoint."""
    from warpbridge.model.effects import Effects
    from warpbridge.model.excitation import filtered_random
    from warpbridge.model.plant import Plant, PlantStepper

    effects = Effects(aero_gain_per_kpa=1.5, aero_deg_per_kpa=2.0, **slack)
    t = np.arange(0, 10, 0.01)
    w_sp = filtered_random(t, 1.0, 3.0, offset=7.0, seed=5)
    v = 12.0
    errs = {}
    for aware in (True, False):
        ctl = WingController(BoucWenParams.paper(), mode="ff", w0=w_sp[0], u_min=-20, u_max=30)
        if aware:
            ctl.set_effects(effects)
        wing = PlantStepper(Plant(BoucWenParams.paper(), effects), t[0], ctl.step(w_sp[0], None, 0.01, v).u_cmd)
        e = [wing.step(t[k], ctl.step(w_sp[k], None, 0.01, v).u_cmd, v)[0] - w_sp[k] for k in range(1, t.size)]
        errs[aware] = float(np.sqrt(np.mean(np.square(e[100:]))))
    assert errs[True] < 0.03
    assert errs[False] > 5 * errs[True]


@pytest.mark.parametrize("scenario", ["random", "steps"])
def test_the_feed_forward_leads_the_identified_servo(scenario):
    """ff with a model file's servo (its lag, cap and dead band, as identify finds them) through the SITL's own
    servo: a smooth setpoint is followed far closer than with the hysteresis inverted alone, and steps, which
    the servo's speed cap sets the pace of, no worse (the lead never drives the servo past its travel)."""
    from warpbridge.model.effects import Effects
    from warpbridge.sitl.servo_model import ServoModel, ServoSpec

    spec = ServoSpec()
    effects = Effects(servo_tau_s=spec.tau_s, servo_rate_mm_s=spec.max_speed_mm_s,
                      servo_deadband_mm=spec.deadband_us * spec.mm_per_us)
    t = np.arange(0, 10, DT)
    if scenario == "random":
        w_sp = filtered_random(t, 2.0, 3.0, offset=7.0, seed=5)
    else:
        w_sp = 7.0 + 3.0 * np.sign(np.sin(2 * np.pi * 0.4 * t + 0.1))
    errs = {}
    for aware in (True, False):
        ctl = WingController(P, mode="ff", w0=float(w_sp[0]), u_min=-20, u_max=30)
        if aware:
            ctl.set_effects(effects)
        u0 = ctl.step(float(w_sp[0]), None, DT).u_cmd
        servo = ServoModel(spec, t0=t[0], pulse0_us=spec.pulse_of(u0))
        wing = Stepper(P, w0=float(w_sp[0]))
        e = []
        for k in range(1, t.size):
            u = ctl.step(float(w_sp[k]), None, DT).u_cmd
            e.append(wing.forward_step(servo.step(t[k] + DT, spec.pulse_of(u))) - w_sp[k])
        e = np.asarray(e[100:])
        settled = np.array([np.all(w_sp[max(k - 30, 0):k + 1] == w_sp[k]) for k in range(1, t.size)])[100:]  # 0.3 s
        errs[aware] = [float(np.sqrt(np.mean(x ** 2))) for x in (e, e[settled] if settled.any() else e)]
    if scenario == "random":
        assert errs[True][0] < 0.1 * errs[False][0]
    else:  # the transitions go at the cap either way; once there, the servo rests where the model asked
        assert errs[True][0] < 1.01 * errs[False][0]
        assert errs[True][1] < 0.5 * errs[False][1]
