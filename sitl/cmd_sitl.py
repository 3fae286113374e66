"""``warpbridge sitl``: the whole system simulated, over real UDP and a real pty.

Three parts run at once: the mock autopilot (a subprocess streaming the
scenario's aileron PWM over MAVLink UDP to the bridge, with a ground-station
port), the virtual servo board (a Pololu Maestro emulator on a pty, in this
process, whose servo channels drive the two simulated wings and whose analog
inputs return their flex sensors), and the bridge itself (a subprocess,
``warpbridge run --config <generated toml>``). The scenario runs in real time
for ``--duration`` seconds of control; then the children are stopped, the RMS
tracking error per wing is computed from the bridge's cycle log and the wings'
true warp (row i of the log is the bridge's i-th read of the left sensor), the
same scenario is flown in lock-step for comparison, and the table and a plot
are written. Everything (config, roll file, logs, PNG, summary) stays in
``--out``. ``--lockstep`` instead prints the lock-step comparison table of all
controller modes, calm and in gusts (seconds, no sockets).

Examples::

    warpbridge sitl                                   # 20 s of the paper's random reference
    warpbridge sitl --scenario gust12 --duration 30
    warpbridge sitl --effects 'delay=0.03,backlash=0.2' --model MODEL.json
    warpbridge sitl --lockstep
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import math
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

from bridge.controller import MODES
from bridge.errors import UserError
from model.boucwen import BoucWenParams
from model.effects import EFFECT_FIELDS, Effects
from model.modelfile import ModelFile
from model.plant import Plant
from sitl.lockstep import SETTLE_S, RunResult, compare, rig_config, run_lockstep
from sitl.maestro_emu import MaestroEmulator
from sitl.report import comparison_table, plot_run, run_table
from sitl.scenarios import SCENARIO_NAMES, WINGS, Rig, Scenario, make_scenario
from sitl.wing import SITL_AERO_LOAD, SimWing, WingSpec

log = logging.getLogger(__name__)

STARTUP_MARGIN_S = 20.0  # roll file beyond the run, for the processes to come up
STARTUP_TIMEOUT_S = 30.0
AGREE_TOLERANCE = 0.20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=SCENARIO_NAMES, default=None,
                        help="what the FC commands (default: random; --lockstep: random, gust7, gust12)")
    parser.add_argument("--duration", type=float, default=20.0, metavar="S",
                        help="seconds of control to run (default 20)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output directory (default ./sitl-run-<time>)")
    parser.add_argument("--lockstep", action="store_true",
                        help="print the lock-step comparison of all controller modes instead (fast)")
    parser.add_argument("--effects", default="",
                        help="unmodelled effects of the simulated wing, e.g. 'delay=0.03,backlash=0.2' "
                             f"(names: {', '.join(EFFECT_FIELDS)}; two-parameter effects take a:b)")
    parser.add_argument("--model", type=Path, default=None,
                        help="MODEL.json the simulated wing follows (params and effects; default: the paper's)")
    parser.add_argument("--bridge-model", default="paper",
                        help="model the bridge's feed-forward uses: 'paper' or a MODEL.json (default paper)")
    parser.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--mode", choices=MODES, default="ff+pi", help="bridge controller mode (real-time run)")
    parser.add_argument("--kp", type=float, default=None, help="PI gain, mm/deg (default: the config's 7)")
    parser.add_argument("--ki", type=float, default=None, help="PI gain, mm/(deg s) (default: the config's 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the reference, gusts and noise")
    parser.add_argument("--no-plot", action="store_true", help="skip the PNG")


# ------------------------------------------------------------------ options


def parse_effects(text: str) -> Effects:
    """'delay=0.03,backlash=0.2,pretension=0.3:1.1' -> Effects (names or parameter names)."""
    kw: dict[str, float] = {}
    known = {f.name for f in fields(Effects)}
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise UserError(f"--effects: {item!r} needs a value (name=value)")
        try:
            values = [float(v) for v in value.split(":")]
        except ValueError:
            raise UserError(f"--effects: {item!r}: not a number") from None
        if name in EFFECT_FIELDS:
            names = EFFECT_FIELDS[name][0]
            if len(values) > len(names):
                raise UserError(f"--effects: {name} takes at most {len(names)} value(s) ({':'.join(names)})")
            kw.update(zip(names, values, strict=False))
        elif name in known:
            if len(values) != 1:
                raise UserError(f"--effects: {name} takes one value")
            kw[name] = values[0]
        else:
            raise UserError(f"--effects: unknown effect {name!r} (known: {', '.join(EFFECT_FIELDS)})")
    try:
        return Effects(**kw)
    except ValueError as e:
        raise UserError(f"--effects: {e}") from None


def _read_model(path: Path, what: str) -> ModelFile:
    try:
        return ModelFile.from_dict(json.loads(path.read_text(encoding="utf-8")))
    except OSError as e:
        raise UserError(f"{what}: cannot read {path}: {e.strerror or e}") from None
    except ValueError as e:
        raise UserError(f"{what}: {path}: {e}") from None


def wing_spec(model: Path | None, effects: Effects) -> WingSpec:
    """The simulated wing: the paper's (or MODEL.json's) plant, SITL aero load, plus ``effects``."""
    if model is None:
        plant = Plant(BoucWenParams.paper(), SITL_AERO_LOAD)
    else:
        mf = _read_model(model, "--model")
        plant = Plant(mf.params, SITL_AERO_LOAD.merged(mf.effects))
    return WingSpec(plant=plant).with_effects(effects)


def bridge_params(spec: str) -> BoucWenParams:
    return BoucWenParams.paper() if spec == "paper" else _read_model(Path(spec), "--bridge-model").params


# ------------------------------------------------------------------ the real-time run


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that is free now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class VirtualRig:
    """The two simulated wings behind the Maestro emulator, on the wall clock.

    Every servo target and every analog read first advances the wings to now; each read of a
    sensor channel is recorded with the wing's true warp and tendon travel at that instant."""

    def __init__(self, rig: Rig, wings: dict[str, SimWing], clock=time.monotonic) -> None:
        self.rig, self.wings, self.clock = rig, wings, clock
        self.t0 = clock()
        self.servo_of = {ch: w for ch, w in zip(rig.servo_channels, WINGS, strict=True)}
        self.sensor_of = {ch: w for ch, w in zip(rig.sensor_channels, WINGS, strict=True)}
        self.reads: dict[str, list[tuple[float, int, float, float, float]]] = {w: [] for w in WINGS}
        self.targets = 0

    def now(self) -> float:
        return self.clock() - self.t0

    def on_target(self, channel: int, quarter_us: int) -> None:
        wing = self.servo_of.get(channel)
        if wing is None:
            return
        t = self.now()
        self.wings[wing].advance(t)
        self.wings[wing].set_pulse(quarter_us / 4.0)
        self.targets += 1

    def read_analog(self, channel: int) -> int | None:
        wing = self.sensor_of.get(channel)
        if wing is None:
            return None  # a servo channel: the emulator answers its target
        t = self.now()
        w = self.wings[wing]
        w.advance(t)
        counts = w.read_counts()
        self.reads[wing].append((t, counts, w.w_true, w.u_mm, w.airspeed))
        return counts

    def tick(self) -> None:
        """Keep the wings' time current between the bridge's calls."""
        t = self.now()
        for w in self.wings.values():
            w.advance(t)


def _tail(path: Path, n: int = 15) -> str:
    try:
        return "\n".join(path.read_text(encoding="utf-8", errors="replace").splitlines()[-n:])
    except OSError:
        return "(no log)"


def _stop_child(proc: subprocess.Popen | None, name: str, sig: int = signal.SIGTERM) -> None:
    if proc is None or proc.poll() is not None:
        return
    try:
        proc.send_signal(sig)
        proc.wait(timeout=5.0)
    except subprocess.TimeoutExpired:
        log.warning("%s did not stop; killing it", name)
        proc.kill()
        proc.wait(timeout=5.0)
    except ProcessLookupError:
        pass


def read_cycle_log(path: Path) -> dict[str, np.ndarray]:
    """The bridge's cycle log as columns (``mode`` as a string array)."""
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise UserError(f"the bridge wrote no cycles to {path}")
    out: dict[str, np.ndarray] = {"mode": np.array([r["mode"] for r in rows])}
    for k in rows[0]:
        if k != "mode":
            out[k] = np.array([float(r[k]) for r in rows])
    return out


def realtime_result(scenario: Scenario, mode: str, cyc: dict[str, np.ndarray], vrig: VirtualRig) -> RunResult:
    """Join the bridge's cycle log with the wings' records (row i = the i-th left-sensor read)."""
    n = min(len(cyc["t"]), *(len(vrig.reads[w]) for w in WINGS))
    if n == 0:
        raise UserError("no control cycles were recorded")
    rec = {w: np.array(vrig.reads[w][:n]) for w in WINGS}
    res = RunResult(
        scenario=scenario.name, mode=mode, t=cyc["t"][:n], airspeed=rec["left"][:, 4],
        setpoint={w: cyc[f"{w}_setpoint"][:n] for w in WINGS},
        warp={w: rec[w][:, 2] for w in WINGS},
        measured={w: cyc[f"{w}_warp"][:n] for w in WINGS},
        u_cmd={w: cyc[f"{w}_u"][:n] for w in WINGS},
        u={w: rec[w][:, 3] for w in WINGS},
    )
    for w in WINGS:  # the join is right if the bridge read back exactly the counts the wing returned
        read = scenario.rig.sensor.deg_of_counts(rec[w][:, 1])
        logged = res.measured[w]
        ok = np.isfinite(logged)
        bad = np.mean(np.abs(read[ok] - logged[ok]) > 1e-3) if ok.any() else 1.0
        if bad > 0.02:
            log.warning("%s wing: %.0f %% of cycle-log rows do not match the sensor reads; RMS may be off",
                        w, 100 * bad)
    flying = cyc["mode"][:n] != "failsafe"
    if not flying.any():
        raise UserError("the bridge never left failsafe: it heard no servo outputs from the mock autopilot")
    first = res.t[np.argmax(flying)]
    res.compute_rms(t_from=first + SETTLE_S)
    return res


def scenario_offset(scenario: Scenario, t: np.ndarray, setpoint: np.ndarray) -> float:
    """Scenario time at log time 0: the shift that best matches the logged setpoint to the reference."""
    ok = np.isfinite(setpoint)
    t, sp = t[ok], setpoint[ok]
    best, best_err = 0.0, math.inf
    for step, span in ((0.05, (0.0, STARTUP_MARGIN_S)), (0.002, None)):
        lo, hi = span if span is not None else (best - 0.1, best + 0.1)
        for tau in np.arange(lo, hi, step):
            err = float(np.mean((scenario.reference(t + tau)["left"] - sp) ** 2))
            if err < best_err:
                best, best_err = float(tau), err
    return best


def run_realtime(args: argparse.Namespace, out: Path, spec: WingSpec) -> int:
    rig = Rig()
    name = args.scenario or "random"
    scenario = make_scenario(name, args.duration + STARTUP_MARGIN_S, rig=rig, seed=args.seed)
    roll_csv = scenario.write_csv(out / "roll.csv")
    fc_port, gcs_port = free_udp_port(), free_udp_port()
    from sitl.lockstep import make_wings

    wings = make_wings(scenario, spec, w0_deg=rig.bias_deg, seed=args.seed)
    vrig = VirtualRig(rig, wings)
    emu = MaestroEmulator(on_target=vrig.on_target, read_analog=vrig.read_analog)
    mock = bridge = None
    bridge_log = out / "bridge-cycles.csv"
    t_start = time.monotonic()
    try:
        pty = emu.start()
        model_file = "paper" if args.bridge_model == "paper" else str(Path(args.bridge_model).resolve())
        kw = {k: v for k, v in (("kp", args.kp), ("ki", args.ki)) if v is not None}
        cfg_path = out / "warpbridge-sitl.toml"
        cfg_path.write_text(rig.config_toml(
            connection=f"udpin:127.0.0.1:{fc_port}", servo_backend=f"maestro:{pty}", sensor_backend="maestro:",
            mode=args.mode, model_file=model_file, log=bridge_log.name, params_file="params.json", **kw),
            encoding="utf-8")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        with (out / "mock-autopilot.log").open("w") as mlog:
            mock = subprocess.Popen(
                [sys.executable, "-m", "sitl.mock_autopilot", "--fc-port", str(fc_port), "--gcs-port", str(gcs_port),
                 "--autopilot", args.autopilot, "--roll-file", str(roll_csv), "--seed", str(args.seed), "-v"],
                stdout=mlog, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        with (out / "bridge.log").open("w") as blog:
            bridge = subprocess.Popen(
                [sys.executable, "-m", "bridge.cli", "-v", "run", "--config", str(cfg_path)],
                stdout=blog, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        print(f"sitl: {scenario.name} ({scenario.description}); mock {args.autopilot} on UDP {fc_port} "
              f"(GCS on udpin:127.0.0.1:{gcs_port}), Maestro emulator on {pty}, output in {out}")
        _wait_for_cycles(args.duration, vrig, mock, bridge, out, loop_hz=100.0)
    finally:
        _stop_child(bridge, "bridge", signal.SIGTERM)  # the bridge closes its log on SIGTERM as on Ctrl-C
        _stop_child(mock, "mock autopilot", signal.SIGTERM)
        emu.stop()
    log.info("real-time run took %.1f s", time.monotonic() - t_start)

    if not bridge_log.exists():
        raise UserError(f"the bridge wrote no cycle log; see {out / 'bridge.log'}:\n{_tail(out / 'bridge.log')}")
    cyc = read_cycle_log(bridge_log)
    rt = realtime_result(scenario, args.mode, cyc, vrig)
    # the same stretch of the same scenario in lock-step
    tau = scenario_offset(scenario, rt.t, rt.setpoint["left"])
    flying = cyc["mode"][: rt.t.size] != "failsafe"
    t_from = rt.t[np.argmax(flying)] + SETTLE_S + tau
    t_to = rt.t[-1] + tau
    ls_sc = make_scenario(name, t_to + 0.5, rig=rig, seed=args.seed)
    cfg = rig_config(rig, args.mode, args.kp, args.ki)
    ls, _ = run_lockstep(ls_sc, mode=args.mode, spec=spec, config=cfg,
                         controller_params=bridge_params(args.bridge_model), seed=args.seed)
    ls.compute_rms(t_from=t_from, t_to=t_to)
    print()
    print(run_table({"real time": rt, "lock-step": ls}))
    rel = {w: abs(rt.rms[w] - ls.rms[w]) / ls.rms[w] for w in WINGS}
    agree = all(v <= AGREE_TOLERANCE for v in rel.values())
    print(f"real time vs lock-step: {', '.join(f'{w} {100 * v:.0f} %' for w, v in rel.items())} apart "
          f"({'agree' if agree else 'DISAGREE'} within {100 * AGREE_TOLERANCE:.0f} %)")
    summary = {"scenario": name, "mode": args.mode, "duration_s": args.duration, "autopilot": args.autopilot,
               "effects": spec.plant.effects.to_dict(), "scenario_offset_s": tau,
               "rms_deg": {"realtime": rt.rms, "lockstep": ls.rms}, "agree": agree, "cycles": int(rt.t.size)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    if not args.no_plot:
        png = plot_run(rt, out / "sitl.png", title=f"SITL real time: {name}, {args.mode}")
        print(f"plot: {png}")
    print(f"logs: {out}")
    return 0


def _wait_for_cycles(duration: float, vrig: VirtualRig, mock, bridge, out: Path, loop_hz: float) -> None:
    """Advance the wings until the bridge has run ``duration`` s of cycles; fail if a child dies."""
    from tqdm import tqdm

    target = int(duration * loop_hz)
    deadline = time.monotonic() + duration * 3 + STARTUP_TIMEOUT_S
    started = None
    with tqdm(total=round(duration, 1), unit="s", desc="sitl", leave=False,
              disable=not sys.stderr.isatty()) as bar:
        while True:
            vrig.tick()
            n = len(vrig.reads["left"])
            if n and started is None:
                started = time.monotonic()
            bar.n = round(min(n / loop_hz, duration), 1)
            bar.refresh()
            if n >= target:
                return
            for proc, name, logf in ((mock, "mock autopilot", "mock-autopilot.log"), (bridge, "bridge", "bridge.log")):
                if proc.poll() is not None:
                    raise UserError(f"the {name} exited with status {proc.returncode}; "
                                    f"{out / logf}:\n{_tail(out / logf)}")
            if time.monotonic() > deadline:
                raise UserError(f"the bridge ran only {n} cycles of {target} in time; see {out / 'bridge.log'}")
            time.sleep(0.005)


# ------------------------------------------------------------------ entry point


def main(args: argparse.Namespace) -> int:
    if not args.duration > 0:
        raise UserError("--duration must be positive")
    spec = wing_spec(args.model, parse_effects(args.effects))
    if args.lockstep:
        scenarios = (args.scenario,) if args.scenario else ("random", "gust7", "gust12")
        print(f"lock-step, {args.duration:g} s per run; simulated wing effects: "
              f"{spec.plant.effects.to_dict() or 'none'}")
        rows = compare(scenarios, duration_s=args.duration, spec=spec, kp=args.kp, ki=args.ki, seed=args.seed,
                       controller_params=bridge_params(args.bridge_model))
        print(comparison_table(rows))
        return 0
    out = args.out or Path(f"sitl-run-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    # Ctrl-C and SIGTERM both unwind through run_realtime's clean-up (even where SIGINT was ignored)
    old = {s: signal.signal(s, _raise_interrupt) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        return run_realtime(args, out, spec)
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt
