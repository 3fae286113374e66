"""``warpbridge run --config warpbridge.toml [--check] [--duration S]``: run the bridge on a real FC.

``--check`` validates the config and the model, opens the servo and sensor
backends, reads each wing's sensor once, tries the link for a few seconds, asks
the FC what each wing's source output does (``bridge.outputcheck``) and prints
what it found; exit status 0 if everything answered and both sources are aileron
outputs, 2 otherwise. Without it the bridge runs until interrupted (Ctrl-C or
SIGTERM stop it cleanly).

Start-up order: the config (standard library only), then neutral on the servo
board (``bridge.startup``: the model file and the serial port), then the rest of
the bridge (MAVLink). The model's kernels run interpreted here (``model._jit``):
one sample per wing per cycle needs no compiler, and the process stays small;
``WARPBRIDGE_JIT=1`` compiles them with numba instead.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from pathlib import Path

from warpbridge.bridge.config import Config, backend_has_sensor, load_config
from warpbridge.bridge.errors import UserError
from warpbridge.bridge.instance_lock import InstanceLock

log = logging.getLogger(__name__)

CHECK_LINK_S = 5.0
CHECK_OUTPUTS_S = 6.0  # the output-function check asks up to three times, 1.5 s apart


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", "-c", type=Path, default=Path("warpbridge.toml"),
                        help="configuration file (default: warpbridge.toml; see warpbridge.example.toml)")
    parser.add_argument("--check", action="store_true",
                        help="validate the config, open the devices, try the link, report and exit")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds (bench tests)")


def check(config: Config, link_timeout: float = CHECK_LINK_S) -> int:
    """Open everything once and say what answered; 0 if all did, 2 otherwise."""
    from warpbridge.bridge.link import FcLink
    from warpbridge.bridge.signing import policy_from_config
    from warpbridge.bridge.startup import load_model, servo_limits
    from warpbridge.hw import DeviceError, open_sensor, open_servo, sensor_on_servo_port

    ok = True
    model = load_model(config)
    print(f"config: OK; model: {'paper' if config.model_file is None else config.model_file}"
          f" (a2 = {model.a2:g} mm/deg)")
    for w in config.wings.values():
        print(f"  {w.name} wing: FC output {w.source_channel}{' reversed' if w.reverse else ''}, "
              f"warp 0..{w.max_warp_deg:g} deg (bias {w.bias_deg:g}), servo channel {w.servo_channel}, "
              f"sensor channel {w.sensor_channel if w.sensor_channel is not None else '-'}, "
              f"mode {w.control.mode}")
    link = FcLink(config.link.connection, servo_rate_hz=config.link.servo_rate_hz,
                  source_system=config.link.source_system, signing=policy_from_config(config.link))
    servo = sensor = None
    try:
        try:
            servo = open_servo(config.servo_backend, mavlink_sender=link, limits=servo_limits(config))
            print(f"servo: {config.servo_backend}: opened")
        except (ValueError, DeviceError) as e:
            ok = False
            print(f"servo: {config.servo_backend}: FAILED: {e}")
        try:
            if servo is None and sensor_on_servo_port(config.sensor_backend, config.servo_backend):
                raise DeviceError("not read: it is on the servo's Maestro, which did not open", "maestro")
            sensor = open_sensor(config.sensor_backend, shared_servo=servo)
            if backend_has_sensor(config.sensor_backend):
                for w in config.wings.values():
                    if w.sensor_channel is None:
                        continue
                    raw = sensor.read_counts(w.sensor_channel)
                    lo, hi = min(w.sensor.counts), max(w.sensor.counts)
                    good = raw is not None and lo <= raw <= hi
                    ok &= good
                    print(f"sensor: {w.name} channel {w.sensor_channel}: {raw!r} counts"
                          f"{'' if good else f' FAILED (expected {lo:g}..{hi:g})'}")
            else:
                print("sensor: none (feed-forward only)")
        except (ValueError, DeviceError) as e:
            ok = False
            print(f"sensor: {config.sensor_backend}: FAILED: {e}")
        print(f"link: {config.link.connection}: waiting up to {link_timeout:g} s for the FC ...")
        if link.connect(link_timeout):
            print(f"link: FC system {link.system_id} ({link.autopilot}), armed={link.armed}")
            deadline = link.clock() + min(2.0, link_timeout)
            while link.servo_time is None and link.clock() < deadline:
                link.poll()
                if link.mav is not None:
                    link.mav.select(0.05)
            if link.servo_time is None:
                ok = False
                print("link: FAILED: no servo output messages (SERVO_OUTPUT_RAW / ACTUATOR_OUTPUT_STATUS)")
            else:
                chans = sorted({w.source_channel for w in config.wings.values()})
                print("link: servo outputs " + ", ".join(f"{c}: {link.servo_pwm.get(c)}" for c in chans))
            ok &= check_outputs(config, link)
        else:
            ok = False
            if link.open_error is not None:
                print(f"link: FAILED: cannot open {config.link.connection}: {link.open_error}")
            else:
                print("link: FAILED: no autopilot heartbeat")
    finally:
        for dev in {id(d): d for d in (sensor, servo) if d is not None}.values():
            try:
                dev.close()
            except Exception:  # noqa: BLE001
                log.exception("closing device failed")
        link.close()
    print("check: OK" if ok else "check: FAILED")
    return 0 if ok else 2


def check_outputs(config: Config, link, timeout: float = CHECK_OUTPUTS_S) -> bool:
    """Ask the FC what each wing's source output does and print it; False if one is not an aileron."""
    from warpbridge.bridge.outputcheck import OutputFunctionCheck

    probe = OutputFunctionCheck(link, {w.name: w.source_channel for w in config.wings.values()})
    deadline = link.clock() + timeout
    while not probe.done and link.clock() < deadline:
        probe.take(link.poll(), link.clock())
        if link.mav is not None:
            link.mav.select(0.05)
    good = True
    for name in config.wings:
        v = probe.verdicts.get(name)
        if v is None:
            print(f"outputs: {name} wing: no answer from the FC in {timeout:g} s")
            continue
        good &= v.kind != "not_aileron"
        tag = {"aileron": "OK", "mixed": "NOTE", "unknown": "WARNING", "not_aileron": "FAILED"}[v.kind]
        print(f"outputs: {v.text()}: {tag}")
    return good


def main(args: argparse.Namespace) -> int:
    from warpbridge.model import _jit

    config = load_config(args.config)
    _jit.interpret()  # before anything imports the model's kernels
    with InstanceLock(config.params_file).acquire("run --check" if args.check else "run"):
        return _main(args, config)


def _main(args: argparse.Namespace, config: Config) -> int:
    if args.check:
        return check(config)
    if args.duration is not None and not args.duration > 0:
        raise UserError("--duration must be positive")
    from warpbridge.bridge.startup import command_neutral, servo_limits

    opened = command_neutral(config, servo_limits(config))  # the wings to neutral before anything else loads
    from warpbridge.bridge.app import run_bridge

    stop = threading.Event()

    def on_signal(signum, frame) -> None:  # noqa: ARG001
        log.warning("signal %d: stopping", signum)
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    from warpbridge.bridge import realtime

    realtime.apply(config.loop)  # priority, affinity, locked memory, gc frozen: as far as permitted
    try:
        result = run_bridge(config, stop_event=stop, duration=args.duration, opened_servo=opened)
    except KeyboardInterrupt:
        return 0
    log.info("stopped after %d cycles", result.cycles)
    return 0
