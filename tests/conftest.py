"""Helpers shared by the real-time MAVLink tests of every folder: free loopback ports, a sim vehicle,
a delivery run."""

from __future__ import annotations

import asyncio
import contextlib
import time

import pytest

from companion.config import load_config, shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.telemetry.loopback import free_tcp_port
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config


def shipped_config(params: str = "sitl_short.toml", *, simulated: bool = True, **tables):
    """A shipped params file with some of its tables' keys overridden (``mission={...}``,
    ``sim={...}``: read_params merges them into the file's): the simulator's config, or with
    ``simulated=False`` the companion's alone (load_config)."""
    load = load_simulated_config if simulated else load_config
    return load(shipped_params_path(params), overrides=tables or None)


def short_config(**mission):
    """The short scenario (sitl_short.toml) with keys of its [mission] overridden."""
    return shipped_config(mission=mission) if mission else shipped_config()


def firmware_config(firmware: str, connection: str, ready_timeout_s: float, telemetry: dict | None = None):
    """The short scenario (sitl_short.toml) flown on a real firmware ("px4", "ardupilot") at
    ``connection``, with the landing tuning shipped for it (``firmware_tuning``); ``telemetry``: the
    [telemetry] table (default: off)."""
    from companion_lab.real_campaign import firmware_tuning

    tuning = firmware_tuning(firmware)
    return load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "autopilot": firmware,
            "connection": connection,
            "mission": {**tuning["mission"], "ready_timeout_s": ready_timeout_s},
            "landing": tuning["landing"],
            "telemetry": telemetry if telemetry is not None else {"enabled": False},
        },
    )


def connect_only_zenoh(folder, port: int):
    """A Zenoh config file (``folder``/zenoh.toml) of a peer that only connects to the loopback
    listener on ``port``, without scouting; its path."""
    z = folder / "zenoh.toml"
    z.write_text(
        f'[zenoh]\nmode = "peer"\nlisten = []\nconnect = ["tcp/127.0.0.1:{port}"]\n'
        "multicast_scouting = false\ngossip_scouting = false\nscouting_delay_ms = 0\n"
    )
    return z


# A delivery vehicle has its release configured: ArduCopter's gripper library is off by default
# (GRIP_ENABLE = 0: DO_GRIPPER answers FAILED, as the sim vehicle does unless told otherwise).
DELIVERY_PARAMS = {"ardupilot": {"GRIP_ENABLE": 1.0}, "px4": {}}


@contextlib.contextmanager
def sim_vehicle(config, dialect, port, **kwargs):
    kwargs.setdefault("params", DELIVERY_PARAMS[dialect])
    sim = mavlink_sim_vehicle(config.sim, dialect, remote=("127.0.0.1", port), **kwargs).start()
    try:
        yield sim
    finally:
        sim.stop()


async def wait_for(pred, timeout_s: float, what: str = "condition") -> None:
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout_s:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(0.02)


def rangefinder_trace(trace: list):  # type: ignore[no-untyped-def]
    """A monitor for ``fly`` that appends (reading time, range, the estimate's height above the
    ground, phase) to ``trace`` every 50 ms once the route is planned: the rangefinder tests."""

    async def watch(shell) -> None:  # type: ignore[no-untyped-def]
        while True:
            r, est = shell.autopilot.telemetry.rangefinder, shell.estimate
            if r is not None and est is not None and shell.mission.frame is not None:
                trace.append(
                    (r.time_s, r.distance_m, shell.mission.height_above_ground(est), shell.mission.phase.value)
                )
            await asyncio.sleep(0.05)

    return watch


def descent_to_ground(trace: list, ground_m: float):  # type: ignore[no-untyped-def]
    """From a ``rangefinder_trace``: the first row of the final descent (Phase.LANDING_PAD), the
    last row above the ground (the first reading at or below ``ground_m`` ends the descent; the
    lowest reading where the trace ended before one did) and the sink rate over its last 0.3 s."""
    from companion.events import Phase

    first = next(row for row in trace if row[3] == Phase.LANDING_PAD.value)
    start = trace.index(first)
    after = range(start, len(trace))
    ground = next((i for i in after if trace[i][1] <= ground_m), min(after, key=lambda i: trace[i][1]))
    air = trace[start:ground]
    last = air[-1]
    before = next(row for row in reversed(air) if row[0] < last[0] - 0.3)
    return first, last, (before[1] - last[1]) / (last[0] - before[0])


async def fly(config, autopilot, monitor=None, timeout_s: float = 90.0):
    shell = DeliveryShell(config, autopilot)
    mon = asyncio.get_running_loop().create_task(monitor(shell)) if monitor else None
    try:
        summary = await shell.run(timeout_s=timeout_s)
    finally:
        if mon is not None:
            mon.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await mon
            if mon.done() and not mon.cancelled() and mon.exception() is not None:
                raise mon.exception()
        await autopilot.close()
    return shell, summary


async def orders_scenario(
    config, ap, secret: bytes, out_dir, ready_timeout_s: float = 90.0, flight_timeout_s: float = 300.0
):
    """One `fly --orders` session (docs/orders.md) on ``ap``, the ground on a loopback Zenoh peer:
    order 1 (14, 14 m from home) delivered, an order while it flies refused as busy, one 150 m
    away refused as out of range, order 2 (-12, 10 m) delivered. Returns the session and the
    ground's replies by order id."""
    from companion.cli.orders import serve_orders
    from companion.geometry.earth import GeoPoint, ned_to_geo
    from companion.telemetry.ground import GroundStation
    from companion.telemetry.loopback import loopback_settings
    from companion.telemetry.orders import OrderPad

    zport = free_tcp_port()
    events: list = []
    replies: dict = {}
    stop = asyncio.Event()
    station = GroundStation(loopback_settings(connect_port=zport))
    loop = asyncio.get_running_loop()

    async def send(north_m: float, east_m: float, order_id: str):
        h = ap.telemetry.home
        g = ned_to_geo(GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m), north_m, east_m, 0.0)
        pad = OrderPad(g.lat_deg, g.lon_deg)
        replies[order_id] = await asyncio.to_thread(
            station.send_order, config.vehicle_id, pad, secret, order_id=order_id
        )
        return replies[order_id]

    async def until(cond, timeout_s: float, what: str) -> None:
        t0 = loop.time()
        while not cond():
            assert loop.time() - t0 < timeout_s, f"timed out after {timeout_s} s waiting for {what}"
            assert not task.done() or task.exception() is None, task.exception()
            await asyncio.sleep(0.2)

    def flown(order_id: str) -> bool:
        return any(e.detail.startswith(f"order {order_id} flown") for e in events)

    task = loop.create_task(
        serve_orders(
            config,
            ap,
            out_dir,
            zenoh_settings=loopback_settings(listen_port=zport),
            flight_timeout_s=flight_timeout_s,
            stop=stop,
            on_event=events.append,
        )
    )
    try:
        tc = ap.telemetry
        await until(
            lambda: tc.home is not None and tc.status is not None and tc.status.healthy, ready_timeout_s, "ready"
        )
        await asyncio.to_thread(station.start)
        for _ in range(50):  # until the ground's session reaches the desk's queryable
            if (await send(14.0, 14.0, "o-1")).replied:
                break
            await asyncio.sleep(0.1)
        assert replies["o-1"].accepted, replies["o-1"]
        await until(lambda: tc.status.armed, 120.0, "order 1 armed")
        await send(-12.0, 10.0, "o-busy")
        await until(lambda: flown("o-1"), flight_timeout_s, "order 1 flown")
        await send(0.0, 150.0, "o-far")
        assert (await send(-12.0, 10.0, "o-2")).accepted, replies["o-2"]
        await until(lambda: flown("o-2"), flight_timeout_s, "order 2 flown")
    finally:
        stop.set()
        session = await asyncio.wait_for(task, 60.0)
        await asyncio.to_thread(station.stop)
    return session, replies


def _firmware_build(firmware: str):
    """The real firmware's build (``"px4"``: PX4 SIH, ``"ardupilot"``: ArduCopter SITL); the test is
    skipped with the reason when it is absent, or fails with COMPANION_REQUIRE_FIRMWARE=1 (CI with
    the builds shipped)."""
    import os

    from companion_firmware.ardupilot_sitl import ArduPilotNotFound, find_ardupilot
    from companion_firmware.px4_sitl import Px4NotFound, find_px4

    try:
        return find_px4() if firmware == "px4" else find_ardupilot()
    except (Px4NotFound, ArduPilotNotFound) as err:
        if os.environ.get("COMPANION_REQUIRE_FIRMWARE") == "1":
            pytest.fail(f"COMPANION_REQUIRE_FIRMWARE=1 but {err}")
        pytest.skip(str(err))


@pytest.fixture(scope="module")
def px4_root():
    return _firmware_build("px4")


@pytest.fixture(scope="module")
def ardupilot_root():
    return _firmware_build("ardupilot")


@pytest.fixture(params=["px4", "ardupilot"])
def firmware(request):
    """A test of tests/real_firmware/ once per real firmware: its name and its build."""
    return request.param, _firmware_build(request.param)


@pytest.fixture
def udp_port() -> int:
    return free_udp_port()


@pytest.fixture(scope="session")
def mav():
    """The helpers above, for test modules (conftest is not importable under importlib mode)."""
    from types import SimpleNamespace

    return SimpleNamespace(
        free_udp_port=free_udp_port,
        free_tcp_port=free_tcp_port,
        shipped_config=shipped_config,
        short_config=short_config,
        sim_vehicle=sim_vehicle,
        wait_for=wait_for,
        fly=fly,
        rangefinder_trace=rangefinder_trace,
        descent_to_ground=descent_to_ground,
        orders_scenario=orders_scenario,
        firmware_config=firmware_config,
        connect_only_zenoh=connect_only_zenoh,
    )
