"""Remote ID against real PX4 v1.16 SITL (SIH), no flight: the companion's OPEN_DRONE_ID_SYSTEM,
OPERATOR_ID and SELF_ID (MAVSDK MavlinkDirect) land in PX4's uORB topics with our values, read
with PX4's own ``listener`` through its shell client; PX4's OPEN_DRONE_ID_SYSTEM stream, asked
for, carries its home as the operator's location, not ours (docs/remote-id.md)."""

from __future__ import annotations

import asyncio
import json
import subprocess
import time
from typing import Any

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.config import RemoteIdConfig
from companion_firmware.px4_sitl import Px4Sitl

pytestmark = pytest.mark.firmware

RID = RemoteIdConfig(
    enabled=True,
    uas_id="SN42",
    operator_id="FIN87astrdge12k8",
    self_id="parcel delivery",
    operator_location="fixed",
    operator_lat_deg=47.3977000,
    operator_lon_deg=8.5456000,
    operator_alt_m=500.0,
)
MAV_CMD_SET_MESSAGE_INTERVAL = 511
OPEN_DRONE_ID_SYSTEM_ID = 12904


def listener(sitl: Px4Sitl, topic: str) -> str:
    """PX4's ``listener TOPIC -n 1`` through the running SITL's shell client."""
    client = sitl.build_dir / "bin" / "px4-listener"
    cmd = [str(client), "--instance", str(sitl.instance), topic, "-n", "1"]
    rootfs = sitl.build_dir / "rootfs" / str(sitl.instance)
    done = subprocess.run(cmd, cwd=rootfs, capture_output=True, text=True, timeout=20.0, check=False)
    return done.stdout


async def test_px4_takes_operator_id_self_id_and_system(px4_root, tmp_path):
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log") as sitl:
        ap = Px4Autopilot("udpin://127.0.0.1:14540")
        ap.remote_id = RID
        await ap.connect(timeout_s=30.0)
        streamed: dict[str, Any] = {}

        async def watch() -> None:
            async for m in ap._direct.subscribe_message("OPEN_DRONE_ID_SYSTEM"):
                if m.system_id == ap.system_id:
                    streamed.update(json.loads(m.fields_json))

        watcher = asyncio.create_task(watch())
        try:
            await ap._direct_command(
                "OPEN_DRONE_ID_SYSTEM at 1 Hz", MAV_CMD_SET_MESSAGE_INTERVAL, OPEN_DRONE_ID_SYSTEM_ID, 1e6
            )
            t0 = time.monotonic()
            while ap.remote_id_sent < 6 or not streamed:
                assert time.monotonic() - t0 < 20.0, (ap.remote_id_sent, streamed)
                await asyncio.sleep(0.2)
            system = await asyncio.to_thread(listener, sitl, "open_drone_id_system")
            operator = await asyncio.to_thread(listener, sitl, "open_drone_id_operator_id")
            selfid = await asyncio.to_thread(listener, sitl, "open_drone_id_self_id")
        finally:
            watcher.cancel()
            await ap.close()
    assert "operator_latitude: 473977000" in system and "operator_longitude: 85456000" in system, system
    assert "operator_location_type: 2" in system and "operator_altitude_geo: 500.0" in system, system
    assert 'operator_id: "FIN87astrdge12k8"' in operator and "operator_id_type: 0" in operator, operator
    assert 'description: "parcel delivery"' in selfid and "description_type: 0" in selfid, selfid
    # v1.16's stream: the operator at home (type takeoff), whatever we sent
    assert streamed["operator_location_type"] == 0
    assert abs(streamed["operator_latitude"] - 473977000) > 100, streamed
