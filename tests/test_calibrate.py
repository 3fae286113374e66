"""Self-calibration in the running bridge: the arming interlock (parameter and MAV_CMD_USER_1), aborts,
the held-out acceptance applied per wing, persistence and the rollback by WB_CAL_REST; online adaptation
switched on and off. The whole ``Bridge`` runs in lock-step against simulated wings (``sitl.field_tuning``)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.calibrate import CalState, cal_path
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.params import ParamError
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import Effects
from warpbridge.sitl.field_tuning import DriftingPretension, SimBoard, SimLink
from warpbridge.sitl.lockstep import make_wings, rig_config
from warpbridge.sitl.scenarios import Rig, make_scenario
from warpbridge.sitl.wing import WingSpec

RIGGED = Effects(pretension_offset_mm=0.7, pretension_gain=1.08)


class Harness:
    """The bridge, the 'FC' and both simulated wings on one simulated clock (10 ms per tick)."""

    def __init__(self, folder, rigged: Effects | None = RIGGED, mode: str = "ff") -> None:
        rig = Rig()
        self.cfg = replace(rig_config(rig, mode), params_file=folder / "params.json")
        self.t = 0.0
        o = rigged.pretension_offset_mm if rigged else 0.0
        g = rigged.pretension_gain if rigged else 1.0
        self.wings = make_wings(make_scenario("random", 5.0, rig=rig), WingSpec(), w0_deg=rig.bias_deg)
        for w in self.wings.values():
            w.plant = DriftingPretension(w.spec.plant, 0.0, w.servo.mm, lambda _t: o, lambda _t: g)
        self.link = SimLink()
        board = SimBoard(rig, self.wings, lambda: self.t)
        self.bridge = Bridge(self.cfg, servo=board, sensor=board, link=self.link, clock=lambda: self.t)
        self.bridge.store.set("WB_CAL_SEC", 10.0)
        self.pwm = {rig.aileron_channel: rig.pwm_trim}
        self.run(0.5)

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / 0.01)):
            self.t += 0.01
            for w in self.wings.values():
                w.advance(self.t)
            self.link.servo_pwm, self.link.servo_time = self.pwm, self.t
            self.bridge.tick()

    def calibrate(self) -> None:
        """Run the started calibration to its end (the fit's worker thread awaited)."""
        tuning = self.bridge.tuning
        while tuning.running:
            if tuning.state == CalState.FITTING:
                tuning.wait_fit(30.0)
            self.run(0.01)

    def command(self, action: float, src: int = 255):
        msg = mavlink.MAVLink_command_long_message(1, 191, mavlink.MAV_CMD_USER_1, 0, action, 0, 0, 0, 0, 0, 0)
        msg._header = mavlink.MAVLink_header(msg.id, srcSystem=src, srcComponent=190)
        self.link.inbox.append(msg)
        self.run(0.01)
        acks = [m for m in self.link.sent if m.get_type() == "COMMAND_ACK" and m.command == 31010]
        return acks[-1]

    def models(self) -> dict[str, BoucWenParams]:
        return {n: w.ctl._model.params for n, w in self.bridge.wings.items()}

    def close(self) -> None:
        self.bridge.close()


@pytest.fixture
def rig(tmp_path):
    h = Harness(tmp_path)
    yield h
    h.close()


def test_calibration_is_refused_while_armed_by_parameter_and_by_command(rig):
    rig.link.armed = True
    with pytest.raises(ParamError, match="armed"):
        rig.bridge.store.set("WB_CAL_RUN", 1)
    assert rig.bridge.store.get("WB_CAL_RUN") == 0 and not rig.bridge.tuning.running
    ack = rig.command(1)
    assert ack.result == mavlink.MAV_RESULT_DENIED and ack.target_system == 255
    assert not rig.bridge.tuning.running
    assert any("refused while armed" in t for t in rig.link.texts)
    with pytest.raises(ParamError, match="armed"):
        rig.bridge.store.set("WB_CAL_REST", 1)
    rig.link.armed = False
    rig.link.fc_alive = False  # no heartbeat: nobody can say it is disarmed
    assert rig.command(1).result == mavlink.MAV_RESULT_DENIED
    rig.link.fc_alive = True
    assert rig.command(1).result == mavlink.MAV_RESULT_ACCEPTED
    assert rig.bridge.tuning.running and rig.bridge.store.get("WB_CAL_RUN") == 1
    assert rig.command(1).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # one at a time


def test_arming_during_the_excitation_aborts_and_gives_the_wings_back(rig):
    before = rig.models()
    rig.bridge.store.set("WB_CAL_RUN", 1)
    rig.run(3.0)
    assert rig.bridge.tuning.state == CalState.EXCITING
    assert all(w.ctl.mode == "ff" for w in rig.bridge.wings.values())
    rig.link.armed = True
    rig.run(0.02)
    tuning = rig.bridge.tuning
    assert not tuning.running and tuning.state == CalState.ABORTED and tuning.last_reason == "armed"
    assert "WB cal aborted: armed" in rig.link.texts
    assert all(w.ctl.mode == "ff" for w in rig.bridge.wings.values())  # the configured mode again
    assert rig.models() == before and rig.bridge.store.get("WB_CAL_RUN") == 0


def test_calibration_applies_a_passing_model_persists_it_and_can_be_rolled_back(rig, tmp_path):
    base = rig.models()
    rig.bridge.store.set("WB_CAL_RUN", 1)
    rig.calibrate()
    tuning = rig.bridge.tuning
    assert tuning.state == CalState.APPLIED, rig.link.texts
    for name in ("left", "right"):
        res = tuning.last_results[name]
        assert res.accepted and res.transform.offset == pytest.approx(0.7, abs=0.1)
        assert res.transform.gain == pytest.approx(1.08, abs=0.02)
    calibrated = rig.models()
    assert calibrated["left"] != base["left"]
    assert rig.bridge.store.get("WB_CAL_RUN") == 0
    assert any(t.startswith("WB cal L: new model applied") for t in rig.link.texts)
    doc = json.loads(cal_path(rig.cfg.params_file).read_text())
    assert doc["wings"]["left"]["current"]["transform"]["offset_mm"] == pytest.approx(0.7, abs=0.1)
    # a restarted bridge flies the calibrated model
    rig.bridge.close()
    again = Bridge(rig.cfg, servo=SimBoard(Rig(), rig.wings, lambda: rig.t),
                   sensor=SimBoard(Rig(), rig.wings, lambda: rig.t), link=rig.link, clock=lambda: rig.t)
    rig.bridge = again
    assert rig.models() == calibrated
    rig.run(0.02)
    # rollback: the previous (base) model, and setting it again undoes the rollback
    rig.bridge.store.set("WB_CAL_REST", 1)
    assert rig.models() == base
    assert rig.link.texts[-1] == "WB cal restored: left base model; right base model"  # what flies now
    rig.run(0.05)
    assert rig.bridge.store.get("WB_CAL_REST") == 0  # a one-shot
    rig.bridge.store.set("WB_CAL_REST", 1)
    assert rig.models() == calibrated
    offset = tuning.last_results["left"].transform.offset
    assert rig.link.texts[-1].startswith(f"WB cal restored: left {offset:+.2f} mm, gain ")
    assert rig.command(3).result == mavlink.MAV_RESULT_ACCEPTED  # the same by command
    assert rig.models() == base


def test_a_model_that_still_fits_is_kept_and_the_reason_reported(tmp_path):
    h = Harness(tmp_path, rigged=None)
    try:
        before = h.models()
        h.bridge.store.set("WB_CAL_RUN", 1)
        h.calibrate()
        assert h.bridge.tuning.state == CalState.KEPT
        assert h.models() == before
        assert any(t.startswith("WB cal L: kept old model: old model still fits") for t in h.link.texts)
        assert not cal_path(h.cfg.params_file).exists()
        with pytest.raises(ParamError, match="no previous model"):
            h.bridge.store.set("WB_CAL_REST", 1)
    finally:
        h.close()


def test_online_adaptation_moves_the_feed_forward_and_returns_when_switched_off(rig):
    from warpbridge.sitl.lockstep import FcOutputs

    rig.bridge.store.set("WB_ADAPT", 1)
    rig.link.armed = True
    fc = FcOutputs(make_scenario("random", 40.0, rig=Rig()), 100.0)
    t0 = rig.t
    for _ in range(3000):  # 30 s of flight
        rig.pwm = fc.poll(rig.t - t0)
        rig.run(0.01)
    est = rig.bridge.tuning.est["left"].estimate
    assert 0.2 < est.offset <= 0.7 + 0.1 and est.gain > 1.0
    assert rig.link.named["L_ad_off"] == pytest.approx(est.offset, abs=0.05)
    assert rig.bridge.store.get("WB_ADL_OFF") == pytest.approx(est.offset, abs=0.05)
    with pytest.raises(ParamError, match="armed"):  # and no calibration in flight
        rig.bridge.store.set("WB_CAL_RUN", 1)
    rig.bridge.store.set("WB_ADAPT", 0)
    rig.run(10.0)
    off = rig.bridge.tuning.est["left"].estimate
    assert off.offset == pytest.approx(max(0.0, est.offset - 0.2), abs=0.03)  # 0.02 mm/s back to neutral
