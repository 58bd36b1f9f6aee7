"""Zenoh session settings: a frozen, validated dataclass turned into a ``zenoh.Config``.

Deployment shapes:

- **single vehicle, peer-to-peer** (default): vehicle and ground are peers; either listens, the
  other connects (or, on a trusted LAN, multicast scouting finds the other side).
- **fleet**: the ground station runs as the Zenoh *router* (``companion ground --router``,
  ``mode="router"`` with a listen endpoint); every vehicle connects to it as a peer or client
  with ``router_endpoint="tcp/<ground>:7447"``.

Zenoh's own transport authentication (user/password, ``transport.auth.usrpwd``): the side that
*accepts* connections gives ``auth_dictionary_file`` (lines ``user:password``); the side that
*opens* them gives ``user`` and ``password``. A peer that both listens and connects gives all
three. Sessions presenting wrong or no credentials are refused at the transport, before any
key expression is exchanged. The dictionary file, and a session file that holds ``password``,
are refused when their group or others can read or write them (:mod:`companion.secret_files`).
Use TLS (``tls/`` endpoints, configured through ``overrides``)
on untrusted networks: usrpwd alone does not encrypt.

Transport limits, applied before a byte reaches Python: Zenoh reassembles a message from its
fragments and drops it once it passes ``transport/link/rx/max_message_size`` (``max_message_bytes``,
256 KiB here against Zenoh's 1 GiB), so a hostile 900 MB query costs the vehicle at most that much
memory and never a copy into Python. Shared memory is off (a local peer could otherwise hand over a
buffer of any size without fragments), and ``max_sessions`` / ``accept_pending`` bound the peers
and half-open connections a session keeps (Zenoh's defaults: 1000 and 100).

See ``params/zenoh_*.toml`` for example files (a ``[zenoh]`` table) and :func:`load_settings`.
"""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import zenoh

from companion.secret_files import exposed_secret

Mode = Literal["peer", "client", "router"]
_MODES = ("peer", "client", "router")
#: (setting, lowest, highest): a message limit below Zenoh's 64 KiB batch would cut every batch
_LIMITS = (
    ("max_message_bytes", 64 * 1024, 1 << 30),
    ("max_sessions", 1, 10_000),
    ("accept_pending", 1, 10_000),
)
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream|unixpipe|serial|vsock)/\S+$")


class SettingsError(ValueError):
    """A Zenoh setting is invalid (the message names the key and the reason)."""


class SessionOpenError(RuntimeError):
    """Zenoh refused to open a session with valid settings (endpoint in use, router unreachable
    with ``connect_exit_on_failure``); the message names the endpoints and Zenoh's reason."""


def _zenoh_reason(err: Exception) -> str:
    """Zenoh's error text without the Rust source locations it appends (`` at .../x.rs:12.``)."""
    return re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(err)).strip()


@dataclass(frozen=True)
class ZenohSettings:
    """How to open the Zenoh session.

    ``listen``/``connect``: endpoints such as ``tcp/127.0.0.1:7447``; ``None`` keeps Zenoh's
    default (a peer listens on ``tcp/[::]:0`` - every interface), an empty tuple means none.
    ``router_endpoint``: the fleet router to connect to (added to ``connect``).
    ``scouting_delay_ms``: how long ``open`` waits for scouting replies (Zenoh's default 500 ms
    in peer mode; 0 for fast start-up when the endpoints are explicit).
    ``connect_exit_on_failure``: fail ``open`` when no connect endpoint can be reached (or
    refuses our credentials) within ``connect_timeout_ms`` instead of retrying in background.
    ``overrides``: extra ``(json5 key path, json5 value)`` pairs applied last, for anything else
    Zenoh supports (TLS certificates, ``transport/link/tx/...``).
    ``max_message_bytes``: the largest message Zenoh reassembles (larger ones are dropped by
    Zenoh, counted in nothing of ours); ``shared_memory``: Zenoh's shared-memory transport;
    ``max_sessions`` / ``accept_pending``: ``None`` keeps Zenoh's default.
    """

    mode: Mode = "peer"
    listen: tuple[str, ...] | None = None
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = True
    router_endpoint: str | None = None
    gossip_scouting: bool = True
    scouting_delay_ms: int | None = None
    connect_exit_on_failure: bool = False
    connect_timeout_ms: int | None = None
    user: str | None = None
    password: str | None = field(default=None, repr=False)
    auth_dictionary_file: str | None = None
    overrides: tuple[tuple[str, str], ...] = ()
    max_message_bytes: int = 256 * 1024
    shared_memory: bool = False
    max_sessions: int | None = None
    accept_pending: int | None = None

    def __post_init__(self) -> None:
        if self.mode not in _MODES:
            raise SettingsError(f"zenoh.mode: {self.mode!r} is not one of {', '.join(_MODES)}")
        for key in ("listen", "connect"):
            value = getattr(self, key)
            if value is None:
                continue
            if isinstance(value, str) or not isinstance(value, tuple):
                raise SettingsError(f"zenoh.{key}: expected a tuple of endpoints, got {value!r}")
            for ep in value:
                _check_endpoint(f"zenoh.{key}", ep)
        if self.router_endpoint is not None:
            _check_endpoint("zenoh.router_endpoint", self.router_endpoint)
        if self.mode == "router" and not self.listen:
            raise SettingsError("zenoh.listen: a router needs at least one listen endpoint")
        if self.mode == "client" and not self.all_connect_endpoints and self.multicast_scouting is False:
            raise SettingsError("zenoh.connect: a client without multicast scouting needs a connect or router endpoint")
        if (self.user is None) != (self.password is None):
            raise SettingsError("zenoh.user and zenoh.password go together")
        if self.auth_dictionary_file is not None and not Path(self.auth_dictionary_file).is_file():
            raise SettingsError(f"zenoh.auth_dictionary_file: {self.auth_dictionary_file!r} is not a file")
        if self.auth_dictionary_file is not None:  # Zenoh reads it: its passwords must be the owner's only
            exposed = exposed_secret(self.auth_dictionary_file, "zenoh.auth_dictionary_file")
            if exposed is not None:
                raise SettingsError(str(exposed))
        for key in ("scouting_delay_ms", "connect_timeout_ms"):
            value = getattr(self, key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                raise SettingsError(f"zenoh.{key}: expected an integer >= 0, got {value!r}")
        for key, low, high in _LIMITS:
            value = getattr(self, key)
            if value is None and key != "max_message_bytes":
                continue
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise SettingsError(f"zenoh.{key}: expected an integer in [{low}, {high}], got {value!r}")
        for pair in self.overrides:
            if not (isinstance(pair, tuple) and len(pair) == 2 and all(isinstance(x, str) for x in pair)):
                raise SettingsError(f"zenoh.overrides: expected (key, json5 value) pairs, got {pair!r}")

    @property
    def all_connect_endpoints(self) -> tuple[str, ...]:
        eps = tuple(self.connect)
        if self.router_endpoint is not None and self.router_endpoint not in eps:
            eps = (*eps, self.router_endpoint)
        return eps

    def to_config(self) -> zenoh.Config:
        """The ``zenoh.Config`` these settings describe."""
        conf = zenoh.Config()
        for key, value in self.json5_items():
            try:
                conf.insert_json5(key, value)
            except Exception as e:  # zenoh raises ZError / ValueError for bad keys and values
                raise SettingsError(f"zenoh config {key} = {value}: {e}") from e
        return conf

    def json5_items(self) -> list[tuple[str, str]]:
        """The ``(key, json5 value)`` pairs inserted into the config, in order."""
        items: list[tuple[str, str]] = [("mode", json.dumps(self.mode))]
        if self.listen is not None:
            items.append(("listen/endpoints", json.dumps(list(self.listen))))
        items.append(("connect/endpoints", json.dumps(list(self.all_connect_endpoints))))
        items.append(("scouting/multicast/enabled", json.dumps(self.multicast_scouting)))
        items.append(("scouting/gossip/enabled", json.dumps(self.gossip_scouting)))
        if self.scouting_delay_ms is not None:
            items.append(("scouting/delay", json.dumps(self.scouting_delay_ms)))
        if self.connect_exit_on_failure:
            items.append(("connect/exit_on_failure", "true"))
        if self.connect_timeout_ms is not None:
            items.append(("connect/timeout_ms", json.dumps(self.connect_timeout_ms)))
        if self.user is not None:
            items.append(("transport/auth/usrpwd/user", json.dumps(self.user)))
            items.append(("transport/auth/usrpwd/password", json.dumps(self.password)))
        if self.auth_dictionary_file is not None:
            items.append(("transport/auth/usrpwd/dictionary_file", json.dumps(str(self.auth_dictionary_file))))
        items.append(("transport/link/rx/max_message_size", json.dumps(self.max_message_bytes)))
        items.append(("transport/shared_memory/enabled", json.dumps(self.shared_memory)))
        if self.max_sessions is not None:
            items.append(("transport/unicast/max_sessions", json.dumps(self.max_sessions)))
        if self.accept_pending is not None:
            items.append(("transport/unicast/accept_pending", json.dumps(self.accept_pending)))
        items.extend(self.overrides)
        return items

    def open(self) -> zenoh.Session:
        """Open a session with these settings (raises ``zenoh.ZError`` when Zenoh refuses)."""
        return zenoh.open(self.to_config())

    def open_or_explain(self) -> zenoh.Session:
        """:meth:`open`, with Zenoh's refusal as a :class:`SessionOpenError` naming the endpoints."""
        try:
            return self.open()
        except zenoh.ZError as err:
            raise SessionOpenError(
                f"cannot open the Zenoh session (mode {self.mode}, listen {list(self.listen or ())}, "
                f"connect {list(self.all_connect_endpoints)}): {_zenoh_reason(err)}"
            ) from None

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = "zenoh") -> ZenohSettings:
        """Build from a TOML/JSON table; unknown keys and wrong types fail with the key name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise SettingsError(f"{source}: unknown key(s) {', '.join(unknown)}")
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key in ("listen", "connect"):
                if not isinstance(value, list | tuple):
                    raise SettingsError(f"{source}.{key}: expected a list of endpoints")
                value = tuple(value)
            elif key == "overrides":
                if not isinstance(value, Mapping):
                    raise SettingsError(f"{source}.overrides: expected a table of key = json5 string")
                value = tuple((str(k), str(v)) for k, v in value.items())
            elif key in ("multicast_scouting", "gossip_scouting", "connect_exit_on_failure", "shared_memory"):
                if not isinstance(value, bool):
                    raise SettingsError(f"{source}.{key}: expected true/false")
            elif key in ("user", "password", "auth_dictionary_file", "router_endpoint", "mode") and not isinstance(
                value, str
            ):
                raise SettingsError(f"{source}.{key}: expected a string")
            kwargs[key] = value
        try:
            return cls(**kwargs)
        except SettingsError as e:
            raise SettingsError(f"{source}: {e}") from None


def _check_endpoint(key: str, endpoint: Any) -> None:
    if not isinstance(endpoint, str) or not _ENDPOINT.match(endpoint):
        raise SettingsError(f"{key}: {endpoint!r} is not an endpoint like 'tcp/127.0.0.1:7447'")


def load_settings(path: str | Path, table: str = "zenoh") -> ZenohSettings:
    """Read ``[zenoh]`` (or ``table``) from a TOML file into :class:`ZenohSettings`.

    A relative ``auth_dictionary_file`` is resolved against the TOML file's folder.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise SettingsError(f"{path}: {e}") from e
    except UnicodeDecodeError as e:
        raise SettingsError(f"{path}: not UTF-8 text, as TOML must be: {e}") from None
    data = doc.get(table)
    if not isinstance(data, dict):
        raise SettingsError(f"{path}: no [{table}] table")
    outside = sorted(set(doc) - {table})
    if outside:  # a setting written above the table would be silently ignored (a limit not applied)
        raise SettingsError(f"{path}: unknown key(s) outside [{table}]: {', '.join(outside)}")
    data = dict(data)
    if data.get("password") is not None:  # the session file holds a secret: the owner's only
        exposed = exposed_secret(path, "Zenoh session file (it holds zenoh.password)")
        if exposed is not None:
            raise SettingsError(str(exposed))
    dict_file = data.get("auth_dictionary_file")
    if isinstance(dict_file, str) and not Path(dict_file).is_absolute():
        data["auth_dictionary_file"] = str(path.parent / dict_file)
    return ZenohSettings.from_mapping(data, source=f"{path}:{table}")
