"""``warpbridge review``: the join, the analysis and the report.

On the real ArduPlane SITL flight of tests/data (its DataFlash log, the ground station's tlog and the
bridge's cycle log) and on a synthetic flight (``review_synth``) whose clock offset, transit, roll-rate
gains and lag are set by construction, so the expectations come from outside the code under test.
"""

from __future__ import annotations

import json
import math
from argparse import Namespace
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import review_synth as rs

from warpbridge.bridge.commands import review as review_cmd
from warpbridge.bridge.commands.fclog import Series, read_fc_log
from warpbridge.bridge.commands.logjoin import Alignment, align, join_mismatch, read_cycle_log, xcorr_lag
from warpbridge.bridge.commands.review import PHASES, _lost, phases, review
from warpbridge.bridge.errors import UserError

DATA = Path(__file__).parent / "data"
BIN = DATA / "arduplane-flight.BIN"
TLOG = DATA / "arduplane-flight.tlog"
CYCLES = DATA / "arduplane-flight-cycles.csv"


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    fc, cycle = rs.flight()
    folder = tmp_path_factory.mktemp("synth")
    return fc, cycle, read_cycle_log(rs.write_cycle_log(folder / "cycles.csv", cycle))


# ------------------------------------------------------------------------------------------------ stamps


def test_the_link_keeps_the_fcs_stamp_and_the_cycle_log_writes_it(tmp_path):
    """SERVO_OUTPUT_RAW and ACTUATOR_OUTPUT_STATUS carry the FC's boot time: the link keeps the latest
    (``servo_fc_time``, s) and the cycle log writes it as ``fc_t``."""
    import time

    from helpers import free_udp_port

    from warpbridge.bridge.cyclelog import CycleLog as Writer
    from warpbridge.bridge.link import FcLink
    from warpbridge.bridge.mavlink_env import mavlink, mavutil

    port = free_udp_port()
    link = FcLink(f"udpin:127.0.0.1:{port}", servo_rate_hz=50)
    assert link.open()
    peer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=7, source_component=1)
    try:
        def pump(until) -> bool:
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not until():
                link.poll()
                time.sleep(0.002)
            return until()

        peer.mav.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
        assert pump(lambda: link.system_id == 7)
        assert link.servo_fc_time is None
        peer.mav.servo_output_raw_send(123_456_789, 0, 1500, *([0] * 15))
        assert pump(lambda: link.servo_fc_time is not None)
        assert link.servo_fc_time == pytest.approx(123.456789)
        peer.mav.actuator_output_status_send(200_000_000, 4, [1100.0] * 4 + [0.0] * 28)
        assert pump(lambda: link.servo_fc_time == pytest.approx(200.0))
    finally:
        link.close()
        peer.close()
    path = tmp_path / "c.csv"
    with Writer(path) as w:
        for k in range(12):
            w.write(0.01 * k, "ff", None, {"left": {"setpoint": 1.0}, "right": {"setpoint": 2.0}},
                    fc_t=None if k < 2 else 200.0 + 0.02 * (k // 2))
    cl = read_cycle_log(path)
    assert np.isnan(cl.fc_t[:2]).all() and cl.fc_t[2] == pytest.approx(200.02) and cl.fc_t[-1] == pytest.approx(200.1)


# ------------------------------------------------------------------------------------------------ join


def test_xcorr_finds_a_known_shift_below_the_grid():
    t = np.arange(0, 30, 0.013)
    x = np.sin(1.3 * t) + 0.5 * np.sin(0.37 * t + 1) + 0.2 * np.sin(5.1 * t)
    shift = 0.0437
    lag, corr = xcorr_lag(t, x, t + shift, x, -1.0, 1.0)
    assert lag == pytest.approx(shift, abs=0.002) and corr > 0.95
    lag, _ = xcorr_lag(t, x, t - 0.3, -x, -1.0, 1.0)  # the sign is free: a reversed wing
    assert lag == pytest.approx(-0.3, abs=0.002)


def test_join_by_stamps_places_the_cycle_log_on_the_fcs_clock(synthetic):
    fc, _, cl = synthetic
    al = align(cl, fc)
    assert al.method == "fc_t"
    # the offset is the true one less the transit and the shortest wait (not separable from the stamps)
    assert al.offset_s == pytest.approx(rs.OFFSET_S - rs.TRANSIT_S, abs=0.002)
    assert abs(al.drift) < 1e-6
    assert al.check_corr > 0.99 and abs(al.residual_s) < 0.002
    # the FC's logged L_sp (10 Hz, stamped 3 ms after the value) against the cycle log's
    assert al.telemetry_lag_s == pytest.approx(0.003 + rs.TRANSIT_S, abs=0.006)


def test_join_without_stamps_by_cross_correlation(tmp_path, synthetic):
    fc, cycle, _ = synthetic
    cl = read_cycle_log(rs.write_cycle_log(tmp_path / "old.csv", cycle, with_fc_t=False))
    assert cl.fc_t is None
    al = align(cl, fc)
    assert al.method == "xcorr" and math.isnan(al.residual_s)
    assert al.offset_s == pytest.approx(rs.OFFSET_S, abs=0.02)


def test_a_drifting_companion_clock_is_followed(tmp_path):
    fc, cycle = rs.flight(duration=120.0)
    cycle = dict(cycle)
    cycle["t"] = cycle["t"] * (1 + 200e-6)  # the bridge's clock runs 200 ppm fast
    cl = read_cycle_log(rs.write_cycle_log(tmp_path / "drift.csv", cycle))
    al = align(cl, fc)
    assert al.drift == pytest.approx(-200e-6, abs=20e-6)
    assert abs(al.residual_s) < 0.003


# ------------------------------------------------------------------------------------------------ analysis


def test_phases_of_a_triangle_wave():
    t = np.arange(0, 8, 0.01)
    sp = 6 + 4 * (2 * np.abs((t / 4) % 1 - 0.5) - 0.5)  # 4 s triangle: turns at t = 0, 2, 4, 6
    sp[(t > 5.0) & (t < 5.5)] = sp[np.searchsorted(t, 5.0)]  # a half-second hold while falling (4..6 s)
    ph = phases(t, sp)
    name = {k: v for k, v in enumerate(PHASES)}
    assert name[ph[np.searchsorted(t, 1.0)]] == "unloading"
    assert name[ph[np.searchsorted(t, 2.2)]] == "after reversal"
    assert name[ph[np.searchsorted(t, 3.0)]] == "loading"
    assert name[ph[np.searchsorted(t, 5.25)]] == "holding"
    # the hold does not make the continued fall a reversal
    assert name[ph[np.searchsorted(t, 5.6)]] == "unloading"


def test_lost_messages_from_the_stamps():
    stamps = np.arange(0, 10, 0.02)
    kept = np.delete(stamps, [10, 11, 12, 300])
    assert _lost(kept) == (kept.size, 4)


def test_roll_authority_recovers_the_gain_per_airspeed_band(synthetic):
    fc, _, cl = synthetic
    rv, _, _ = review(fc, cl)
    assert rv.roll_lag_s == pytest.approx(rs.ROLL_LAG_S, abs=0.021)
    assert len(rv.roll_authority) >= 4 and rv.roll_uses_measured_warp
    for g in rv.roll_authority:
        if g.n > 500:  # the bands the flight crossed fully: the generator's gain at the band's mean airspeed
            sel = (cl.airspeed >= g.lo_ms) & (cl.airspeed < g.hi_ms)
            assert g.gain == pytest.approx(float(np.mean(rs.gain_at(cl.airspeed[sel]))), rel=0.05), g
            assert g.r2 > 0.9


def test_tracking_error_by_band_and_phase(synthetic):
    fc, cycle, cl = synthetic
    rv, _, al = review(fc, cl)
    left = rv.tracking["left"]
    f0, f1 = fc.span  # the rows the FC's log spans
    inside = (al.fc_time(cycle["t"]) >= f0) & (al.fc_time(cycle["t"]) <= f1)
    assert inside.sum() > cycle["t"].size - 5
    e = (cycle["left"]["warp"] - cycle["left"]["setpoint"])[inside]
    assert left["all"][0].rms == pytest.approx(float(np.sqrt(np.mean(e * e))), rel=1e-6)
    assert sum(s.n for s in left["phase"]) == e.size
    assert {s.label for s in left["phase"]} == set(PHASES)
    assert all(s.n >= review_cmd.MIN_BAND_SAMPLES for s in left["airspeed"])


def test_fc_log_alone_says_the_rate_is_too_low_for_a_diagnosis(synthetic):
    fc, _, _ = synthetic
    rv, flight, al = review(fc, None)
    assert al is None and flight.source == "FC log named values"
    assert flight.rate_hz == pytest.approx(10.0, rel=0.01)
    assert any("too low to tell delay" in w and "WB_TLM_HZ" in w for w in rv.warnings)


def test_review_command_writes_html_and_json(tmp_path, synthetic, monkeypatch):
    fc, cycle, _ = synthetic
    monkeypatch.setattr(review_cmd, "read_fc_log", lambda path, progress=None: fc)
    cyc = rs.write_cycle_log(tmp_path / "c.csv", cycle)
    out = tmp_path / "r.html"
    args = Namespace(log=str(rs.placeholder_log(tmp_path)), cyclelog=str(cyc), output=str(out), channel=None,
                     bands="9,15,21,24", trim=1500.0, half_range=400.0, no_progress=True)
    assert review_cmd.main(args) == 0
    page = out.read_text()
    assert page.count("data:image/png;base64,") == 6 and "Roll authority" in page
    js = json.loads(out.with_suffix(".json").read_text())
    assert js["format"] == "warpbridge-review/1"
    assert [g["band"] for g in js["roll_authority"]] == ["9-15 m/s", "15-21 m/s", "21-24 m/s"]
    assert js["alignment"]["method"] == "fc_t"
    with pytest.raises(UserError, match="--bands"):
        review_cmd.main(Namespace(**{**vars(args), "bands": "x"}))


# ------------------------------------------------------------------------------------------------ real flight


@pytest.fixture(scope="module")
def real():
    fc = read_fc_log(BIN)
    cl = read_cycle_log(CYCLES)
    return fc, cl, review(fc, cl)


def test_real_flight_joins_by_stamps_and_the_check_agrees(real):
    fc, cl, (rv, flight, al) = real
    assert cl.fc_t is not None and al.method == "fc_t"
    assert al.check_corr > 0.9, al
    assert abs(al.residual_s) < 0.02, al  # within a cycle of the FC's 50 Hz output
    assert al.overlap_s > 20
    # the bridge's setpoint placed on the FC's clock follows the FC's logged output through the mixer
    a = (flight.aileron - 1500.0) / 400.0
    expect = np.where(a >= 0, 6 + 6 * np.clip(a, 0, 1), 6 * (1 + np.clip(a, -1, 0)))
    f0, f1 = fc.span
    tf = al.fc_time(cl.t)
    mode = cl.mode[(tf >= f0) & (tf <= f1)]
    ok = np.isfinite(expect) & np.char.startswith(mode.astype(str), "ff")
    assert np.median(np.abs(flight.wings["left"].setpoint[ok] - expect[ok])) < 0.3


def test_a_cycle_log_of_another_flight_is_called_out(real):
    """The PX4 flight's cycle log given with the ArduPlane flight's DataFlash log: its stamps place it, but its
    setpoint does not follow that FC's aileron output, and the review says so; the right pair raises nothing."""
    fc, _, (rv, _, _) = real
    assert not any("another flight" in w for w in rv.warnings), rv.warnings
    other, _, al = review(fc, read_cycle_log(DATA / "px4-flight-cycles.csv"))
    assert al.method == "fc_t" and abs(al.residual_s) > 0.1
    said = [w for w in other.warnings if "another flight" in w]
    assert len(said) == 1 and f"|r| {al.check_corr:.2f}" in said[0], other.warnings


@pytest.mark.parametrize(("corr", "lag_ms", "expected_ms", "called_out"), [
    (0.999, 9.5, 9.5, False),
    (0.94, 22.0, 9.0, False),  # PX4's outputs at 10 Hz
    (0.70, 9.5, 9.0, True),  # stamps that place it, values that do not follow
    (0.99, 600.0, 9.0, True),
])
def test_a_join_is_called_out_by_its_correlation_or_its_residual(corr, lag_ms, expected_ms, called_out):
    al = Alignment("fc_t", 0.0, check_lag_s=lag_ms / 1e3, expected_lag_s=expected_ms / 1e3, check_corr=corr)
    assert (join_mismatch(al) is not None) is called_out


def test_real_flight_tracking_roll_authority_and_link(real):
    fc, cl, (rv, flight, al) = real
    assert rv.source == "cycle log" and rv.rate_hz > 50
    for w in ("left", "right"):
        s = rv.tracking[w]["all"][0]
        assert s.n > 1000 and s.rms < 2.0
        ph = {p.label: p for p in rv.tracking[w]["phase"]}
        assert all(p.n > 500 for p in ph.values()), ph
        # the wing lags its setpoint: below it while it rises, above it while it falls; worst after a turn
        assert ph["loading"].mean < 0 < ph["unloading"].mean
        assert ph["after reversal"].rms > ph["holding"].rms
    # right stick: the left wing gains lift (left - right > 0) and the aircraft rolls right (p > 0)
    fitted = [g for g in rv.roll_authority if g.reliable]
    assert len(fitted) >= 3 and all(g.gain > 0 for g in fitted), rv.roll_authority
    # authority grows with airspeed
    assert fitted[-1].gain > 1.2 * fitted[0].gain
    # the SITL's plane flies FBWA on a roll-rate controller whose feed-forward (autotuned, in the log's
    # parameters) does most of the work: the FF implied by the fitted authority is close to it
    for g in fitted:
        assert g.ff_ardupilot == pytest.approx(fc.params["RLL_RATE_FF"], rel=0.15), g
    assert rv.link.servo_messages > 500 and rv.link.latency_median_ms < 100
    assert {"L_sp", "R_sp"} <= set(rv.link.named_received)


def test_real_flight_from_the_tlog_alone(tmp_path):
    fc = read_fc_log(TLOG)
    rv, flight, _ = review(fc, None)
    assert flight.rate_hz < 20 and rv.warnings
    assert rv.link.tlog_loss


# ------------------------------------------------------------------------------------------------ bad input


def _args(tmp_path, fc_log, cyclelog=None, **kw) -> Namespace:
    base = dict(log=str(fc_log), cyclelog=None if cyclelog is None else str(cyclelog), output=str(tmp_path / "r.html"),
                channel=None, bands=None, trim=1500.0, half_range=400.0, no_progress=True)
    return Namespace(**{**base, **kw})


def _never_read(path, progress=None):
    raise AssertionError("the FC log was read before the options were checked")


def test_a_directory_for_a_log_is_refused_in_one_line(tmp_path, monkeypatch):
    folder = tmp_path / "cycles"
    folder.mkdir()
    with pytest.raises(UserError, match="is a directory"):
        read_cycle_log(folder)
    ulg = tmp_path / "x.ulg"
    ulg.mkdir()
    with pytest.raises(UserError, match="x.ulg: is a directory"):
        read_fc_log(ulg)
    monkeypatch.setattr(review_cmd, "read_fc_log", _never_read)
    with pytest.raises(UserError, match="cycle log .*cycles: is a directory"):
        review_cmd.main(_args(tmp_path, rs.placeholder_log(tmp_path), folder))


@pytest.mark.parametrize(("option", "said"), [
    ({"channel": 0}, "--channel 0: outputs are numbered 1 to 32"),
    ({"channel": -1}, "--channel -1"),
    ({"channel": 33}, "--channel 33"),
    ({"half_range": 0.0}, "--half-range 0"),
    ({"half_range": -400.0}, "--half-range -400"),
    ({"half_range": math.inf}, "--half-range inf"),
    ({"trim": math.nan}, "--trim nan"),
    ({"trim": 15.0}, "--trim 15"),
    ({"output": "x.json"}, "give the HTML report's name"),
])
def test_options_that_cannot_be_right_are_refused_before_reading(tmp_path, monkeypatch, option, said):
    monkeypatch.setattr(review_cmd, "read_fc_log", _never_read)
    if option.get("output"):
        option = {"output": str(tmp_path / option["output"])}
    with pytest.raises(UserError, match=said):
        review_cmd.main(_args(tmp_path, rs.placeholder_log(tmp_path), **option))


def test_an_output_path_that_is_a_directory_or_an_input_is_refused_before_reading(tmp_path, monkeypatch):
    monkeypatch.setattr(review_cmd, "read_fc_log", _never_read)
    fc_log = rs.placeholder_log(tmp_path)
    (tmp_path / "out").mkdir()
    for output in (str(tmp_path / "out"), str(tmp_path / "out") + "/"):
        with pytest.raises(UserError, match="is a directory"):
            review_cmd.main(_args(tmp_path, fc_log, output=output))
    with pytest.raises(UserError, match="would overwrite an input"):
        review_cmd.main(_args(tmp_path, fc_log, output=str(fc_log)))


@pytest.mark.parametrize(("text", "said"), [
    ("nan,20,inf", "finite"), ("20,20", "given twice"), ("-5,5", "negative"), ("x", "not a list"), ("5", "two edges"),
])
def test_band_edges_are_validated(text, said):
    with pytest.raises(UserError, match=said):
        review_cmd.parse_bands(text)
    assert review_cmd.parse_bands("14,10,18") == [10.0, 14.0, 18.0]


# ------------------------------------------------------------------------------------------------ channel, vehicle


def test_channel_is_honoured_with_and_without_the_cycle_log(synthetic):
    fc, _, cl = synthetic
    for c in (cl, None):
        rv, flight, _ = review(fc, c, channel=3)  # output 3 holds 1600 us: not the aileron
        assert flight.aileron_channel == 3 and np.nanmin(flight.aileron) == 1600
        assert all(math.isnan(g.ff_ardupilot) and g.no_ff for g in rv.roll_authority if g.reliable)
        assert any("output 3 (--channel) holds 1600 us" in w for w in rv.warnings)
        rv, flight, _ = review(fc, c)
        assert flight.aileron_channel == 1
        assert any(math.isfinite(g.ff_ardupilot) for g in rv.roll_authority)


def test_a_channel_the_log_cannot_carry_or_did_not_log_is_refused(synthetic):
    fc, _, _ = synthetic
    with pytest.raises(UserError, match="output 9 is not in this log .outputs logged: 1, 3."):
        review(fc, None, channel=9)
    ulog = replace(fc, autopilot="px4", fmt="ulog")
    with pytest.raises(UserError, match="--channel 17: PX4 ULog logs carry outputs 1 to 16"):
        review(ulog, None, channel=17)


def test_a_multirotor_is_refused_unless_the_channel_is_given(synthetic):
    fc, _, _ = synthetic
    quad = replace(fc, mav_type=2, vehicle_source="firmware ArduCopter V4.5.0, FRAME_CLASS 1")
    with pytest.raises(UserError, match="QUADROTOR .firmware ArduCopter.*without a wing.*--channel"):
        review(quad, None)
    rv, _, _ = review(quad, None, channel=1)
    assert any("QUADROTOR" in w and "output 1 reviewed as the aileron" in w for w in rv.warnings)
    rv, _, _ = review(replace(fc, mav_type=1), None)
    assert not any("wing to warp" in w for w in rv.warnings)


def test_a_guessed_aileron_output_is_said(synthetic):
    fc, _, _ = synthetic
    rv, flight, _ = review(replace(fc, aileron_channels=[], params={}), None)
    assert flight.aileron_channel == 1
    assert "no aileron function in the log's parameters: guessed output 1 (use --channel)" in rv.warnings
    rv, _, _ = review(fc, None)
    assert not any("guessed" in w for w in rv.warnings)


def test_a_flaperon_or_elevon_is_the_aileron_when_there_is_none_and_is_said():
    from warpbridge.bridge.commands.fclog import ardupilot_ailerons, px4_ailerons

    flaperons = {"SERVO1_FUNCTION": 19.0, "SERVO2_FUNCTION": 25.0, "SERVO5_FUNCTION": 24.0}
    assert ardupilot_ailerons(flaperons) == [2, 5]  # roll mixed with flaps, in output order
    assert ardupilot_ailerons({**flaperons, "SERVO6_FUNCTION": 4.0}) == [6, 2, 5]  # an aileron first
    elevons = {"PWM_MAIN_FUNC1": 201.0, "PWM_MAIN_FUNC2": 202.0, "CA_SV_CS0_TYPE": 5.0, "CA_SV_CS1_TYPE": 6.0}
    assert px4_ailerons(elevons) == [1, 2]
    assert px4_ailerons({**elevons, "PWM_MAIN_FUNC3": 203.0, "CA_SV_CS2_TYPE": 1.0}) == [3, 1, 2]


def test_a_mixed_roll_output_read_as_the_aileron_is_a_warning(synthetic):
    fc, _, _ = synthetic
    flaperon = replace(fc, aileron_channels=[1], params={**fc.params, "SERVO1_FUNCTION": 24.0})
    rv, flight, _ = review(flaperon, None)
    assert flight.aileron_channel == 1
    assert any(w.startswith("no aileron among the FC's outputs: output 1 (left flaperon) is read as the aileron")
               for w in rv.warnings)
    rv, _, _ = review(flaperon, None, channel=1)  # named by the user: nothing to say
    assert not any("mixed" in w for w in rv.warnings)
    rv, _, _ = review(fc, None)
    assert not any("mixed" in w for w in rv.warnings)


def test_an_unchecked_join_is_a_warning(synthetic):
    fc, _, cl = synthetic
    bare = replace(fc, outputs_t=np.zeros(0), outputs=np.zeros((0, 16)))
    rv, _, al = review(bare, cl)
    assert "alignment not checked: no aileron output in the FC log" in rv.warnings
    assert review_cmd._join_line(al).endswith("not checked")
    rv, _, al = review(fc, cl)
    assert not any("not checked" in w for w in rv.warnings) and "residual" in review_cmd._join_line(al)


def test_a_cycle_log_cut_to_a_shorter_fc_log_is_said(synthetic):
    fc, _, cl = synthetic
    t0 = fc.outputs_t[0]

    def cut(s):
        k = s.t < t0 + 30
        return Series(s.t[k], s.v[k])

    k = fc.outputs_t < t0 + 30
    short = replace(fc, outputs_t=fc.outputs_t[k], outputs=fc.outputs[k], roll_rate=cut(fc.roll_rate),
                    airspeed=cut(fc.airspeed), named={n: cut(s) for n, s in fc.named.items()})
    rv, _, _ = review(short, cl)
    assert "the FC's log covers 30 s of the cycle log's 60 s: the review keeps those" in rv.warnings
    rv, _, _ = review(fc, cl)
    assert not any("covers" in w for w in rv.warnings)


# ------------------------------------------------------------------------------------------------ roll authority


def test_a_band_with_too_few_samples_is_not_fitted(synthetic):
    fc, _, _ = synthetic
    rv, _, _ = review(fc, None, bands=[21.0, 21.5])  # 10 Hz named values: 25 samples in the band
    (g,) = rv.roll_authority
    assert 0 < g.n < review_cmd.MIN_BAND_SAMPLES and not g.reliable and math.isnan(g.ff_ardupilot)
    assert "too few samples to fit" in review_cmd._roll_line(g, px4=False)


def test_bands_below_the_airborne_speed_say_the_fit_leaves_them_out(synthetic):
    fc, _, cl = synthetic
    slow = replace(fc, airspeed=Series(fc.airspeed.t, fc.airspeed.v - 8.0))  # 2..14 m/s
    cycle_slow = replace(cl, airspeed=cl.airspeed - 8.0)
    rv, _, _ = review(slow, cycle_slow, bands=[0.0, 3.0, 6.0, 14.0])
    track = rv.tracking["left"]["airspeed"]
    assert track[0].n > 0 and rv.roll_authority[0].n == 0
    line = review_cmd._roll_line(rv.roll_authority[0], px4=False)
    assert "no samples in this band (the fit leaves out samples below 6 m/s, not airborne)" in line


def test_no_numpy_warnings_on_a_flight_with_unlogged_outputs(synthetic):
    import warnings

    fc, _, cl = synthetic
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        review(replace(fc, aileron_channels=[], params={}), cl)
        review(fc, None, bands=[21.0, 21.5])


def test_an_output_gain_against_the_warp_gain_implies_no_ff(synthetic):
    fc, _, _ = synthetic
    rv, flight, _ = review(fc, None)
    band = max(rv.roll_authority, key=lambda g: g.n)
    assert band.no_ff == "" and band.output_r2 > 0.9 and band.output_gain > 0
    # in that band the FC's output runs against the roll rate, while elsewhere it follows the warp
    sel = (flight.airspeed >= band.lo_ms) & (flight.airspeed < band.hi_ms)
    flight.aileron[sel] = 3000.0 - flight.aileron[sel]
    fits, _ = review_cmd.roll_authority(flight, [(band.lo_ms, band.hi_ms)], 1500.0, 400.0, 15.0)
    assert fits[0].gain > 0 > fits[0].output_gain and math.isnan(fits[0].ff_ardupilot)
    assert "sign disagrees" in fits[0].no_ff and "sign disagrees" in review_cmd._roll_line(fits[0], px4=True)
    assert review_cmd._why_no_ff(20.0, True, -200.0, 0.9, 100, mixer=-1.0) == ""  # a mixer that falls with the output
    assert "fit is unreliable" in review_cmd._why_no_ff(20.0, True, 200.0, 0.1, 100, mixer=1.0)


def test_a_gain_that_rounds_to_zero_is_printed_unsigned():
    g = review_cmd.GainFit("9-12 m/s", 9.0, 12.0, 100, -0.001, 0.0, 0.01, math.nan, math.nan, False)
    assert review_cmd._roll_line(g, px4=False).startswith("roll authority 9-12 m/s: 0.00 deg/s per deg (R2 0.01")
    assert review_cmd.fmt_number(-0.0004, 1) == "0.0" and review_cmd.fmt_number(math.nan) == "-"
