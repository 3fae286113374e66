"""The bridge's configuration: one TOML file read into frozen dataclasses.

``load_config(path)`` reads the file (``tomllib``), checks every key (unknown
keys too, so a typo is not silently ignored) and raises ``UserError`` with one
line naming the file and the key. Relative paths (parameter file, model file,
cycle log) are taken relative to the config file. Every key is documented in
``warpbridge.example.toml`` at the repository root.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from warpbridge.bridge.errors import UserError
from warpbridge.bridge.mixer import WingMix

MODES = ("open", "pi", "ff", "ff+pi")
WINGS = ("left", "right")


@dataclass(frozen=True)
class LinkConfig:
    connection: str  # pymavlink connection string
    source_system: int = 0  # 0 = use the flight controller's system id
    servo_rate_hz: float = 50.0  # requested SERVO_OUTPUT_RAW / ACTUATOR_OUTPUT_STATUS rate
    rerequest_s: float = 5.0  # re-send the message-interval request this often while silent
    gcs_sysid_allow: tuple[int, ...] = ()  # ground stations allowed to set parameters; () = any
    signing_key_file: Path | None = None  # MAVLink 2 signing key (bridge.signing); None = no signing
    signing_accept_unsigned_from_fc: bool = True  # with signing: the FC's own stream may be unsigned
    pwm_jitter_us: float = 2.0  # +- jitter of the FC's servo outputs; sets each wing's setpoint play


@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float = 100.0
    failsafe_timeout_s: float = 0.5  # no servo message for this long -> neutral warp
    sensor_frozen_s: float = 1.0  # identical raw reading this long while the command moves -> sensor bad
    log: Path | None = None  # cycle log CSV; may contain {time}; None = no log
    wake_on_message: bool = True  # run a cycle as soon as the FC's message arrives (plus the fixed ticks)


@dataclass(frozen=True)
class ServoCal:
    pulse_min_us: float = 1000.0
    pulse_max_us: float = 2000.0
    pulse_zero_us: float = 1500.0  # pulse at zero tendon travel
    mm_per_us: float = 0.02  # tendon travel per microsecond (negative if the horn pulls the other way)

    @property
    def mm_limits(self) -> tuple[float, float]:
        """Tendon travel (mm) reachable within the pulse limits, low first."""
        a = (self.pulse_min_us - self.pulse_zero_us) * self.mm_per_us
        b = (self.pulse_max_us - self.pulse_zero_us) * self.mm_per_us
        return min(a, b), max(a, b)


@dataclass(frozen=True)
class SensorCal:
    counts: tuple[float, ...] = (0.0, 1023.0)
    deg: tuple[float, ...] = (0.0, 30.0)


@dataclass(frozen=True)
class ControlConfig:
    mode: str = "ff+pi"
    kp: float = 7.0  # mm of tendon per deg of warp error
    ki: float = 1.0  # mm of tendon per deg*s of integrated error
    i_max_mm: float = 2.0  # limit of the PI integrator in ff+pi (trim authority), mm
    u_min_mm: float | None = None  # tendon limits; None = from the servo calibration
    u_max_mm: float | None = None
    deadband_deg: float = 0.0  # half-width of the setpoint play that feeds the model; derived from
    # [link] pwm_jitter_us through the wing's deg-per-us scaling (not a key of its own)


@dataclass(frozen=True)
class WingConfig:
    name: str
    source_channel: int  # 1-based FC servo output carrying this wing's aileron
    servo_channel: int  # output channel on the servo backend
    reverse: bool = False
    pwm_min: float = 1100.0
    pwm_trim: float = 1500.0
    pwm_max: float = 1900.0
    max_warp_deg: float = 8.0
    bias_deg: float = 0.0
    sensor_channel: int | None = None
    servo: ServoCal = ServoCal()
    sensor: SensorCal = SensorCal()
    control: ControlConfig = ControlConfig()


@dataclass(frozen=True)
class Config:
    base_dir: Path  # directory of the config file; relative paths were resolved against it
    link: LinkConfig
    loop: LoopConfig
    telemetry_rate_hz: float
    params_file: Path
    servo_backend: str
    sensor_backend: str
    model_file: Path | None  # None = the paper's parameters
    wings: dict[str, WingConfig]

    @property
    def left(self) -> WingConfig:
        return self.wings["left"]

    @property
    def right(self) -> WingConfig:
        return self.wings["right"]


class _Section:
    """Typed, validated access to one TOML table; reports errors as ``file: [section] key: ...``."""

    def __init__(self, origin: str, name: str, data: Any) -> None:
        self.origin, self.name = origin, name
        if not isinstance(data, dict):
            raise UserError(f"{origin}: [{name}] must be a table")
        self.data = data
        self.used: set[str] = set()

    def fail(self, key: str, msg: str) -> UserError:
        where = f"[{self.name}] {key}" if self.name else f"[{key}]"
        return UserError(f"{self.origin}: {where}: {msg}")

    def _get(self, key: str, default: Any) -> Any:
        self.used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise self.fail(key, "missing (required)")
            return default
        return self.data[key]

    def num(self, key: str, default: Any = None, *, lo: float = -math.inf, hi: float = math.inf,
            lo_open: bool = False, integer: bool = False) -> Any:
        v = self._get(key, default)
        if v is None or (v is default and key not in self.data):
            return v
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise self.fail(key, f"must be a {'whole ' if integer else ''}number, got {v!r}")
        if integer and int(v) != v:
            raise self.fail(key, f"must be a whole number, got {v!r}")
        if v < lo or v > hi or (lo_open and v == lo):
            rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise self.fail(key, f"must be in {rng}, got {v!r}")
        return int(v) if integer else float(v)

    def text(self, key: str, default: Any = None, *, choices: tuple[str, ...] = ()) -> Any:
        v = self._get(key, default)
        if v is default and key not in self.data:
            return v
        if not isinstance(v, str) or not v.strip():
            raise self.fail(key, f"must be a non-empty string, got {v!r}")
        if choices and v not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)}; got {v!r}")
        return v.strip()

    def flag(self, key: str, default: bool) -> bool:
        v = self._get(key, default)
        if not isinstance(v, bool):
            raise self.fail(key, f"must be true or false, got {v!r}")
        return v

    def numbers(self, key: str, default: Any, *, integer: bool = False) -> tuple:
        v = self._get(key, default)
        if not isinstance(v, list | tuple):
            raise self.fail(key, f"must be a list of numbers, got {v!r}")
        for x in v:
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x) \
                    or (integer and int(x) != x):
                raise self.fail(key, f"must be a list of {'whole ' if integer else ''}numbers, got {x!r}")
        return tuple(int(x) if integer else float(x) for x in v)

    def table(self, key: str) -> _Section:
        self.used.add(key)
        return _Section(self.origin, f"{self.name}.{key}", self.data.get(key, {}))

    def done(self) -> None:
        extra = sorted(set(self.data) - self.used)
        if extra:
            raise self.fail(extra[0], "unknown key")


_REQUIRED = object()


def _path(sec: _Section, key: str, base: Path, default: Any = _REQUIRED) -> Path | None:
    v = sec.text(key, default)
    if v is None:
        return None
    p = Path(v).expanduser()
    return p if p.is_absolute() else base / p


def _wing(root: _Section, name: str, pwm_jitter_us: float = 2.0) -> WingConfig:
    s = root.table(name)
    if not s.data:
        raise UserError(f"{root.origin}: [wing.{name}] missing (both wings are required)")
    pwm = dict(lo=500.0, hi=2500.0)
    w = dict(
        name=name,
        source_channel=s.num("source_channel", _REQUIRED, lo=1, hi=32, integer=True),
        servo_channel=s.num("servo_channel", _REQUIRED, lo=0, hi=255, integer=True),
        reverse=s.flag("reverse", False),
        pwm_min=s.num("pwm_min", 1100.0, **pwm),
        pwm_trim=s.num("pwm_trim", 1500.0, **pwm),
        pwm_max=s.num("pwm_max", 1900.0, **pwm),
        max_warp_deg=s.num("max_warp_deg", 8.0, lo=0.0, hi=30.0, lo_open=True),
        bias_deg=s.num("bias_deg", 0.0, lo=0.0, hi=30.0),
        sensor_channel=s.num("sensor_channel", None, lo=0, hi=255, integer=True),
    )
    if not w["pwm_min"] < w["pwm_trim"] < w["pwm_max"]:
        raise s.fail("pwm_trim", "must lie strictly between pwm_min and pwm_max")
    if w["bias_deg"] > w["max_warp_deg"]:
        raise s.fail("bias_deg", f"must not exceed max_warp_deg ({w['max_warp_deg']:g})")

    sv = s.table("servo")
    servo = ServoCal(
        pulse_min_us=sv.num("pulse_min_us", 1000.0, lo=400, hi=2600),
        pulse_max_us=sv.num("pulse_max_us", 2000.0, lo=400, hi=2600),
        pulse_zero_us=sv.num("pulse_zero_us", 1500.0, lo=400, hi=2600),
        mm_per_us=sv.num("mm_per_us", 0.02, lo=-1.0, hi=1.0),
    )
    if not servo.pulse_min_us < servo.pulse_max_us:
        raise sv.fail("pulse_max_us", "must be greater than pulse_min_us")
    if not servo.pulse_min_us <= servo.pulse_zero_us <= servo.pulse_max_us:
        raise sv.fail("pulse_zero_us", "must lie within [pulse_min_us, pulse_max_us]")
    if servo.mm_per_us == 0.0:
        raise sv.fail("mm_per_us", "must not be zero")
    sv.done()

    se = s.table("sensor")
    counts = se.numbers("counts", (0.0, 1023.0))
    deg = se.numbers("deg", (0.0, 30.0))
    if len(counts) < 2:
        raise se.fail("counts", "needs at least two points")
    if len(deg) != len(counts):
        raise se.fail("deg", f"must have as many entries as counts ({len(counts)})")
    if any(b <= a for a, b in zip(counts, counts[1:], strict=False)):
        raise se.fail("counts", "must be strictly increasing")
    d = [b - a for a, b in zip(deg, deg[1:], strict=False)]
    if not (all(x > 0 for x in d) or all(x < 0 for x in d)):
        raise se.fail("deg", "must be strictly monotone")
    se.done()

    c = s.table("control")
    if "deadband_deg" in c.data:
        raise c.fail("deadband_deg", "no longer a key: the setpoint play is derived from [link] pwm_jitter_us")
    lo_u, hi_u = servo.mm_limits
    ctl = ControlConfig(
        mode=c.text("mode", "ff+pi", choices=MODES),
        kp=c.num("kp", 7.0, lo=0.0, hi=100.0),
        ki=c.num("ki", 1.0, lo=0.0, hi=100.0),
        i_max_mm=c.num("i_max_mm", 2.0, lo=0.0, hi=100.0),
        u_min_mm=c.num("u_min_mm", None, lo=-100.0, hi=100.0),
        u_max_mm=c.num("u_max_mm", None, lo=-100.0, hi=100.0),
    )
    umin = lo_u if ctl.u_min_mm is None else ctl.u_min_mm
    umax = hi_u if ctl.u_max_mm is None else ctl.u_max_mm
    if not umin < umax:
        raise c.fail("u_max_mm", f"must be greater than u_min_mm ({umin:g})")
    c.done()
    s.done()
    mix = WingMix(w["source_channel"], w["reverse"], w["pwm_min"], w["pwm_trim"], w["pwm_max"],
                  w["max_warp_deg"], w["bias_deg"])
    ctl = replace(ctl, deadband_deg=mix.jitter_deadband(pwm_jitter_us))
    return WingConfig(servo=servo, sensor=SensorCal(counts, deg), control=ctl, **w)


def parse_config(data: dict, base: Path, origin: str = "config") -> Config:
    """Validate a parsed TOML document; ``base`` is the directory relative paths start from."""
    root = _Section(origin, "", data)

    def section(name: str) -> _Section:
        root.used.add(name)
        return _Section(origin, name, data.get(name, {}))

    link = section("link")
    link_cfg = LinkConfig(
        connection=link.text("connection", _REQUIRED),
        source_system=link.num("source_system", 0, lo=0, hi=255, integer=True),
        servo_rate_hz=link.num("servo_rate_hz", 50.0, lo=0.0, hi=1000.0, lo_open=True),
        rerequest_s=link.num("rerequest_s", 5.0, lo=0.0, hi=3600.0, lo_open=True),
        gcs_sysid_allow=link.numbers("gcs_sysid_allow", (), integer=True),
        signing_key_file=_path(link, "signing_key_file", base, None),
        signing_accept_unsigned_from_fc=link.flag("signing_accept_unsigned_from_fc", True),
        pwm_jitter_us=link.num("pwm_jitter_us", 2.0, lo=0.0, hi=50.0),
    )
    if any(not 1 <= x <= 255 for x in link_cfg.gcs_sysid_allow):
        raise link.fail("gcs_sysid_allow", "system ids must be in [1, 255]")
    link.done()

    loop = section("loop")
    loop_cfg = LoopConfig(
        rate_hz=loop.num("rate_hz", 100.0, lo=1.0, hi=1000.0),
        failsafe_timeout_s=loop.num("failsafe_timeout_s", 0.5, lo=0.02, hi=60.0),
        sensor_frozen_s=loop.num("sensor_frozen_s", 1.0, lo=0.05, hi=60.0),
        log=_path(loop, "log", base, None),
        wake_on_message=loop.flag("wake_on_message", True),
    )
    loop.done()

    tlm = section("telemetry")
    tlm_rate = tlm.num("rate_hz", 10.0, lo=0.0, hi=100.0)
    tlm.done()

    params = section("params")
    params_file = _path(params, "file", base, "warpbridge-params.json")
    params.done()

    servo = section("servo")
    servo_backend = servo.text("backend", _REQUIRED)
    servo.done()
    sensor = section("sensor")
    sensor_backend = sensor.text("backend", "none")
    sensor.done()

    model = section("model")
    mf = model.text("file", "paper")
    model_file = None if mf == "paper" else _path(model, "file", base)
    model.done()

    root.used.add("wing")
    wing_root = _Section(origin, "wing", data.get("wing", {}))
    wings = {name: _wing(wing_root, name, link_cfg.pwm_jitter_us) for name in WINGS}
    wing_root.done()
    root.done()

    for name, wing in wings.items():
        other = wings["right" if name == "left" else "left"]
        if wing.servo_channel == other.servo_channel:
            raise UserError(f"{origin}: [wing.{name}] servo_channel: both wings use channel {wing.servo_channel}")
    return Config(base_dir=base, link=link_cfg, loop=loop_cfg, telemetry_rate_hz=tlm_rate,
                  params_file=params_file, servo_backend=servo_backend, sensor_backend=sensor_backend,
                  model_file=model_file, wings=wings)


def backend_has_sensor(spec: str) -> bool:
    """Whether a ``[sensor] backend`` string names a real sensor (not ``none``)."""
    return spec.strip().lower() not in ("none", "")


def load_config(path: str | Path, loads: Callable[[str], dict] = tomllib.loads) -> Config:
    """Read and validate a TOML config file; raises ``UserError`` with the offending key."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot read config {p}: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise UserError(f"{p}: not a TOML text file (byte {e.start} is not UTF-8)") from None
    try:
        data = loads(text)
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{p}: not valid TOML: {e}") from None
    return parse_config(data, p.resolve().parent, origin=str(p))
