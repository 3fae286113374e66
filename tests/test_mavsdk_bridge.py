"""MAVSDK (4.x, native library) as the ground station of the bridge process.

The bridge runs as ``warpbridge run`` behind the mock autopilot (which routes like
ArduPilot); MAVSDK connects to the mock's GCS port, selects component 191, reads
and sets a WB_* parameter and receives the bridge's NAMED_VALUE_FLOAT telemetry.
Skipped when mavsdk is not installed or its native library cannot load here.
"""

from __future__ import annotations

import json
import time

import pytest
from test_bridge_process import Rig, wait_for

pytest.importorskip("mavsdk", reason="mavsdk not installed (pip install mavsdk)")
try:
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.mavlink_direct import MavlinkDirect
    from mavsdk.plugins.param import Param, ParamError, ParamResult, ProtocolVersion
except (ImportError, OSError) as e:  # the native library did not load
    pytest.skip(f"mavsdk native library unusable here: {e}", allow_module_level=True)


def select_component(param: Param, component_id: int) -> None:
    """mavsdk 4.x raises ParamError(UNKNOWN) when select_component succeeds (a known quirk)."""
    try:
        param.select_component(component_id, ProtocolVersion.V1)
    except ParamError as e:
        if e.result not in (ParamResult.SUCCESS, ParamResult.UNKNOWN):
            raise


def test_mavsdk_reads_sets_and_receives_telemetry_from_the_bridge_process(tmp_path):
    rig = Rig(tmp_path)
    drone = None
    try:
        rig.start()
        rig.gcs.close()  # MAVSDK takes the GCS port
        drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        drone.add_any_connection(f"udpin://127.0.0.1:{rig.gcs_port}")
        system = drone.first_autopilot(10.0)
        assert system is not None, "MAVSDK saw no autopilot through the mock"
        assert wait_for(lambda: 191 in system.component_ids(), 10.0)

        param = Param(system)
        select_component(param, 191)
        assert param.get_param_float("WB_KP") == pytest.approx(7.0)
        assert param.get_param_int("WB_MODE") == 3  # an integer, cast into the float field as ArduPilot does
        param.set_param_float("WB_KP", 4.5)
        assert param.get_param_float("WB_KP") == pytest.approx(4.5)
        assert wait_for(lambda: (tmp_path / "params.json").exists()
                        and json.loads((tmp_path / "params.json").read_text())["params"].get("WB_KP") == 4.5, 5.0)
        with pytest.raises(ParamError):  # refused: the echo keeps the old value
            param.set_param_float("WB_KP", 500.0)
        assert param.get_param_float("WB_KP") == pytest.approx(4.5)

        seen: list[dict] = []
        direct = MavlinkDirect(system)
        direct.subscribe_message(
            "NAMED_VALUE_FLOAT",
            lambda m, _ud: seen.append(json.loads(m.fields_json)) if m.component_id == 191 else None,
        )
        assert wait_for(lambda: any(str(d.get("name", "")).rstrip("\x00") == "L_sp" for d in seen), 10.0)
        time.sleep(0.2)
        sp = [d["value"] for d in seen if str(d.get("name", "")).rstrip("\x00") == "L_sp"]
        assert sp[-1] == pytest.approx(2.0)  # aileron at trim: the bias
    finally:
        if drone is not None:
            drone.destroy()
        rig.close()
    assert "Traceback" not in rig.stderr()
