"""``warpbridge simulate``: write a log from a chosen plant and excitation (for demos and tests).

The plant is the paper's model or any MODEL.json, optionally with unmodelled
effects switched on; the excitation drives the tendon so that the warp spans
``--warp-range`` on the plant's loading branch. Output: CSV ``t,u,warp,airspeed``.
"""

from __future__ import annotations

import argparse

import numpy as np

from warpbridge.bridge.commands.effects_spec import help_text, parse_effects
from warpbridge.bridge.commands.logfile import write_csv_atomic
from warpbridge.bridge.commands.modelio import load_model
from warpbridge.bridge.errors import UserError
from warpbridge.model import excitation
from warpbridge.model.boucwen import inverse
from warpbridge.model.plant import Plant

EXCITATIONS = ("random", "sine", "sweep", "multisine", "steps")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, help="CSV log to write")
    p.add_argument("--plant", default="paper", help="'paper' (default) or a MODEL.json")
    p.add_argument("--excitation", choices=EXCITATIONS, default="random",
                   help="tendon input: filtered random (paper), sine, sweep 0.5-3 Hz, multisine, steps")
    p.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    p.add_argument("--rate", type=float, default=500.0, help="samples per second (default 500)")
    p.add_argument("--warp-range", default="2:12",
                   help="warp span, deg 'lo:hi', the tendon input is scaled to (through the plant's loading branch); "
                        "the true warp stays inside it, and spans less where the input seldom reaches its ends "
                        "(default 2:12)")
    p.add_argument("--cutoff", type=float, default=1.0, help="random input cut-off, Hz (default 1)")
    p.add_argument("--freq", type=float, default=1.0, help="sine frequency, Hz (default 1)")
    p.add_argument("--noise", type=float, default=0.05, help="warp sensor noise, deg RMS (default 0.05)")
    p.add_argument("--airspeed", default="0", help="m/s: a constant, or 'lo:hi' for a slowly varying flow")
    p.add_argument("--effects", default="", help=f"unmodelled effects: {help_text()}")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def _range(text: str, name: str) -> tuple[float, float]:
    try:
        parts = [float(x) for x in text.split(":")]
    except ValueError:
        raise UserError(f"{name} must be a number or 'lo:hi' (got {text!r})") from None
    if len(parts) == 1:
        return parts[0], parts[0]
    if len(parts) != 2 or parts[1] < parts[0]:
        raise UserError(f"{name} must be 'lo:hi' with lo <= hi (got {text!r})")
    return parts[0], parts[1]


MAX_SAMPLES = 1e8  # 2.3 days at 500 Hz; a CSV of several GB


def simulate_log(plant: Plant, excitation_name: str, duration: float, rate: float, warp_range: tuple[float, float],
                 noise: float, airspeed: tuple[float, float], seed: int = 0, cutoff: float = 1.0,
                 freq: float = 1.0) -> dict[str, np.ndarray]:
    """Columns t, u, warp, airspeed of a simulated log."""
    if not (duration > 0 and rate > 0):
        raise UserError("duration and rate must be positive")
    if not duration * rate <= MAX_SAMPLES:
        raise UserError(f"duration x rate gives {duration * rate:.3g} samples; at most {MAX_SAMPLES:.0e}")
    n = int(round(duration * rate))
    if n < 10:
        raise UserError("duration x rate gives fewer than 10 samples")
    t = np.arange(n) / rate
    # tendon span that drives the warp over warp_range on the loading branch
    w_lo, w_hi = warp_range
    leg = np.linspace(max(0.0, w_lo - 1.0), w_hi, 200)
    u_leg, _ = inverse(plant.params, np.concatenate([leg, leg[::-1], leg]))
    u_lo, u_hi = float(np.interp(w_lo, leg, u_leg[-leg.size:])), float(u_leg[-1])
    off, amp = 0.5 * (u_lo + u_hi), 0.5 * (u_hi - u_lo)
    if excitation_name == "random":
        u = excitation.filtered_random(t, cutoff, amp, off, seed=seed)
    elif excitation_name == "sine":
        u = excitation.sine(t, freq, amp, off)
    elif excitation_name == "sweep":
        u = excitation.sweep(t, 0.5, 3.0, amp, off)
    elif excitation_name == "multisine":
        u = excitation.multisine_reversals(t, (0.6 * amp, 0.28 * amp, 0.12 * amp), (0.4, 1.1, 2.7), off)
    else:
        u = excitation.steps(t, (u_lo, off, u_hi, off), hold_s=2.0)
    v_lo, v_hi = airspeed
    if v_hi > v_lo:
        v = excitation.filtered_random(t, min(0.1, rate / 4), 0.5 * (v_hi - v_lo), 0.5 * (v_lo + v_hi), seed=seed + 7)
    else:
        v = np.full(n, v_lo)
    _, w_meas = plant.simulate(t, u, v)
    rng = np.random.default_rng(seed + 1)
    w_meas = w_meas + noise * rng.standard_normal(n)
    return {"t": t, "u": u, "warp": w_meas, "airspeed": v}


def main(args: argparse.Namespace) -> int:
    if args.seed < 0:
        raise UserError("--seed must be 0 or more")
    if not args.noise >= 0:
        raise UserError("--noise must be 0 or more")
    mf = load_model(args.plant)
    effects = mf.effects.merged(parse_effects(args.effects))
    plant = Plant(mf.params, effects)
    cols = simulate_log(plant, args.excitation, args.duration, args.rate, _range(args.warp_range, "--warp-range"),
                        args.noise, _range(args.airspeed, "--airspeed"), args.seed, args.cutoff, args.freq)
    write_csv_atomic(args.output, cols)
    active = ", ".join(effects.active()) or "none"
    print(f"wrote {args.output}: {cols['t'].size} samples, {args.duration:g} s at {args.rate:g} Hz, "
          f"{args.excitation} excitation, warp {cols['warp'].min():.2f}..{cols['warp'].max():.2f} deg, "
          f"effects: {active}")
    return 0
