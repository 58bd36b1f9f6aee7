"""Zenoh session settings confined to 127.0.0.1 (tests, benches, a ground station on the same
machine): explicit endpoints, no scouting, and a free port to listen on."""

from __future__ import annotations

import socket

from companion.telemetry.session import ZenohSettings


def free_tcp_port() -> int:
    """A currently free TCP port on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def loopback_settings(listen_port: int | None = None, connect_port: int | None = None) -> ZenohSettings:
    """Peer settings confined to 127.0.0.1: explicit endpoints, no multicast, fast open."""
    return ZenohSettings(
        mode="peer",
        listen=(f"tcp/127.0.0.1:{listen_port}",) if listen_port is not None else (),
        connect=(f"tcp/127.0.0.1:{connect_port}",) if connect_port is not None else (),
        multicast_scouting=False,
        gossip_scouting=False,
        scouting_delay_ms=0,
        connect_exit_on_failure=connect_port is not None,
        connect_timeout_ms=3000 if connect_port is not None else None,
    )


def client_settings(router_port: int) -> ZenohSettings:
    """Client settings for a fleet member: connect to the loopback router only, no scouting."""
    return ZenohSettings(
        mode="client",
        listen=None,
        connect=(f"tcp/127.0.0.1:{router_port}",),
        multicast_scouting=False,
        gossip_scouting=False,
        scouting_delay_ms=0,
        connect_exit_on_failure=True,
        connect_timeout_ms=3000,
    )
