"""MAVLink 2 message signing: the key file, the signing timestamp and what ArduPilot does.

A signed MAVLink 2 packet carries a 13-byte signature block: link id (1 byte), a 48-bit
timestamp in 10 us units since 2015-01-01 00:00:00 UTC, and the first 6 bytes of
SHA-256(secret_key + header + payload + CRC + link id + timestamp). The receiver keeps the last
timestamp per (link id, system, component) stream and drops packets whose timestamp does not
grow; a stream it has not seen before is accepted if its timestamp is at most 60 s behind the
receiver's own.

The 32-byte secret comes from a key file (:func:`read_key_file`) in one of three forms:

- ``hex``: 64 hexadecimal digits (whitespace and a trailing newline are ignored), what
  ``companion signing keygen`` writes;
- ``raw``: exactly 32 bytes;
- ``passphrase``: one line of text; the secret is SHA-256 of its UTF-8 bytes, as MAVProxy's
  ``signing setup PASSPHRASE`` makes it (so the same passphrase signs in MAVProxy and here).

``auto`` takes 64 hex digits as ``hex`` and any other 32-byte file as ``raw``; a passphrase file
must be named as such (``signing.key_format = "passphrase"``): a 32-character passphrase would
otherwise read as a raw key. A key file its group or others can read or write is refused
(:mod:`companion.secret_files`): ``chmod 600`` it.

What ArduPilot does (libraries/GCS_MAVLink/GCS_Signing.cpp, 4.x): SETUP_SIGNING (id 256,
target system/component, secret_key, initial_timestamp) stores the key and timestamp and turns
signing on for every link at once; it is refused while armed ("Won't setup signing when armed",
recent versions) and is not acknowledged. The vehicle starts its own timestamp 60 s past the
stored one and raises it to GPS time on a fix. From then on it signs what it sends and drops
unsigned or wrongly signed packets, except on channel 0 (SERIAL0: USB on a flight controller,
TCP 5760 in SITL), which it trusts, and except RADIO_STATUS and RADIO (telemetry radios do not
sign). A key of all zeros with initial timestamp 0 turns signing off again; once signing is on,
that message too must be signed or arrive on channel 0.
"""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from companion.autopilot.interface import AutopilotError
from companion.secret_files import SecretFileExposed, read_private

log = logging.getLogger(__name__)

KEY_LEN = 32
MAVLINK_EPOCH_UNIX_S = 1420070400  # 2015-01-01 00:00:00 UTC
TIMESTAMP_UNITS_PER_S = 100_000  # 10 us
TIMESTAMP_MAX = (1 << 48) - 1
NEW_STREAM_WINDOW = 60 * TIMESTAMP_UNITS_PER_S  # a new stream may lag the receiver's timestamp by 60 s
AP_KEY_LOAD_OFFSET = 60 * TIMESTAMP_UNITS_PER_S  # ArduPilot starts 60 s past its stored timestamp
CLOCK_SANE_AFTER_UNIX_S = 1735689600  # 2025-01-01: a clock before this is not set

MSG_ID_RADIO_STATUS = 109
MSG_ID_RADIO = 166
MSG_ID_SETUP_SIGNING = 256
#: messages ArduPilot accepts unsigned on a signed link (telemetry radios cannot sign)
ACCEPT_UNSIGNED_IDS = frozenset({MSG_ID_RADIO_STATUS, MSG_ID_RADIO})

KeyFormat = Literal["auto", "hex", "raw", "passphrase"]


class SigningError(AutopilotError):
    """The vehicle and we do not sign alike (it drops our packets or we drop its), or it did not
    take a pushed key."""


class SigningKeyError(SigningError):
    """A signing key file or setting is unusable: names the file (or key), the value and what is expected."""


@dataclass(frozen=True)
class SigningKey:
    """A 32-byte MAVLink 2 secret and where it came from (the secret is never printed)."""

    secret: bytes
    source: str

    def __post_init__(self) -> None:
        if len(self.secret) != KEY_LEN:
            raise SigningKeyError(f"{self.source}: a signing key is {KEY_LEN} bytes, got {len(self.secret)}")

    @property
    def fingerprint(self) -> str:
        """First 8 hex digits of SHA-256 of the secret: tells keys apart in logs without revealing them."""
        return hashlib.sha256(self.secret).hexdigest()[:8]

    @property
    def hex(self) -> str:
        return self.secret.hex()

    def __repr__(self) -> str:
        return f"SigningKey(source={self.source!r}, fingerprint={self.fingerprint})"


@dataclass(frozen=True)
class SigningSetup:
    """How a link signs: the key, our link id, whether unsigned packets are accepted, and the
    file our signing timestamp is kept in across restarts (None: start from the clock only)."""

    key: SigningKey
    link_id: int = 1
    allow_unsigned: bool = False
    timestamp_file: Path | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.link_id <= 255:
            raise SigningKeyError(f"signing.link_id = {self.link_id}: must be 0..255")

    def initial_timestamp(self) -> int:
        """Where our timestamp starts: the clock, or 60 s past the one kept in ``timestamp_file``
        if that is later (as ArduPilot restarts from its stored timestamp)."""
        ts = clock_timestamp()
        if self.timestamp_file is not None:
            stored = read_timestamp_file(self.timestamp_file)
            if stored is not None:
                ts = max(ts, min(stored + AP_KEY_LOAD_OFFSET, TIMESTAMP_MAX))
        return ts


def passphrase_key(passphrase: str, source: str = "<passphrase>") -> SigningKey:
    """MAVProxy's ``signing setup PASSPHRASE``: SHA-256 of the passphrase's UTF-8 bytes."""
    if not passphrase:
        raise SigningKeyError(f"{source}: the passphrase is empty")
    return SigningKey(hashlib.sha256(passphrase.encode("utf-8")).digest(), source)


def _parse_hex(text: str, path: str) -> SigningKey:
    digits = "".join(text.split())
    if len(digits) != 2 * KEY_LEN:
        raise SigningKeyError(
            f"{path}: expected {2 * KEY_LEN} hexadecimal digits (a {KEY_LEN}-byte key), got {len(digits)} characters"
        )
    try:
        return SigningKey(bytes.fromhex(digits), path)
    except ValueError:
        bad = next(c for c in digits if c not in "0123456789abcdefABCDEF")
        raise SigningKeyError(
            f"{path}: {bad!r} is not a hexadecimal digit (expected {2 * KEY_LEN} of 0-9a-f)"
        ) from None


def _is_hex(data: bytes) -> bool:
    try:
        digits = "".join(data.decode("ascii").split())
    except UnicodeDecodeError:
        return False
    return len(digits) == 2 * KEY_LEN and all(c in "0123456789abcdefABCDEF" for c in digits)


# where a reader of a parameter file says a key file holds a passphrase
PASSPHRASE_SETTING = "signing.key_format = 'passphrase'"


def parse_key_bytes(data: bytes, fmt: KeyFormat, path: str, passphrase_setting: str = PASSPHRASE_SETTING) -> SigningKey:
    """The key in a key file's bytes (see the module docstring for the formats); ``passphrase_setting``:
    what the reader sets for a passphrase file, named when the bytes are no key (a command line's
    option, or the parameter file's key)."""
    if fmt == "auto":
        if _is_hex(data):
            fmt = "hex"
        elif len(data) == KEY_LEN:
            fmt = "raw"
        else:
            raise SigningKeyError(
                f"{path}: {len(data)} bytes is not a signing key: expected {2 * KEY_LEN} hexadecimal digits "
                f"or exactly {KEY_LEN} raw bytes (a passphrase file needs {passphrase_setting})"
            )
    if fmt == "raw":
        if len(data) != KEY_LEN:
            raise SigningKeyError(f"{path}: a raw key file is exactly {KEY_LEN} bytes, got {len(data)}")
        return SigningKey(bytes(data), path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SigningKeyError(
            f"{path}: not UTF-8 text ({err.reason} at byte {err.start}); expected a {fmt} key"
        ) from None
    if fmt == "hex":
        return _parse_hex(text, path)
    if fmt == "passphrase":
        line = text.removesuffix("\n").removesuffix("\r")
        if "\n" in line or "\r" in line:
            raise SigningKeyError(f"{path}: a passphrase file holds one line, found {len(text.splitlines())}")
        if not line:
            raise SigningKeyError(f"{path}: the passphrase is empty")
        return passphrase_key(line, path)
    raise SigningKeyError(f"{path}: key format {fmt!r} unknown (auto, hex, raw, passphrase)")


def read_key_file(
    path: str | Path, fmt: KeyFormat = "auto", passphrase_setting: str = PASSPHRASE_SETTING
) -> SigningKey:
    """Read a signing key file; :class:`SigningKeyError` names the file and what is expected.
    A key file group or others can read or write is refused (its message names the mode and the
    ``chmod 600``; the :class:`~companion.secret_files.SecretFileExposed` is its cause)."""
    p = Path(path)
    try:
        data = read_private(p, "signing key file")
    except SecretFileExposed as err:
        raise SigningKeyError(str(err)) from err
    except FileNotFoundError:
        raise SigningKeyError(
            f"signing key file {p}: not found (make one with `companion signing keygen {p}`)"
        ) from None
    except IsADirectoryError:
        raise SigningKeyError(f"signing key file {p}: is a directory, expected a file") from None
    except OSError as err:
        raise SigningKeyError(f"signing key file {p}: cannot read: {err.strerror}") from None
    if not data:
        raise SigningKeyError(f"signing key file {p}: empty; expected {2 * KEY_LEN} hex digits or {KEY_LEN} bytes")
    return parse_key_bytes(data, fmt, str(p), passphrase_setting)


def generate_key() -> SigningKey:
    """A new random key from the operating system's CSPRNG."""
    return SigningKey(secrets.token_bytes(KEY_LEN), "<generated>")


def generate_passphrase() -> str:
    """A random passphrase of 40 URL-safe characters (240 bits; no spaces, so MAVProxy takes it)."""
    return secrets.token_urlsafe(30)


def write_key_file(path: str | Path, key: SigningKey | str, *, overwrite: bool = False) -> Path:
    """Write ``key`` as 64 hex digits (or a passphrase ``str``) and a newline, mode 0600. Refuses
    to replace a file unless ``overwrite`` (a replaced key locks out every vehicle set up with the
    old one)."""
    p = Path(path)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if overwrite else os.O_EXCL)
    try:
        fd = os.open(p, flags, 0o600)
    except FileExistsError:
        raise SigningKeyError(f"signing key file {p}: exists; refusing to replace a key (pass --force)") from None
    except OSError as err:
        raise SigningKeyError(f"signing key file {p}: cannot write: {err.strerror}") from None
    with os.fdopen(fd, "w") as fh:
        fh.write((key if isinstance(key, str) else key.hex) + "\n")
    os.chmod(p, 0o600)
    return p


def timestamp_from_unix(unix_s: float) -> int:
    """A MAVLink signing timestamp: 10 us units since 2015-01-01 UTC (0 before then)."""
    return min(max(0, int((unix_s - MAVLINK_EPOCH_UNIX_S) * TIMESTAMP_UNITS_PER_S)), TIMESTAMP_MAX)


def clock_timestamp() -> int:
    """The signing timestamp of the system clock now; warns when the clock is clearly not set
    (a companion without a real-time clock boots in the past, and the vehicle would drop a new
    stream more than 60 s behind its own timestamp: keep one in signing.timestamp_file)."""
    now = time.time()
    if now < CLOCK_SANE_AFTER_UNIX_S:
        log.warning(
            "system clock reads %s: signed packets will carry an old timestamp the vehicle may drop; "
            "set the clock or keep the timestamp in signing.timestamp_file",
            time.strftime("%Y-%m-%d", time.gmtime(now)),
        )
    return timestamp_from_unix(now)


def read_timestamp_file(path: str | Path) -> int | None:
    """The signing timestamp kept in ``path`` (one integer, 10 us units since 2015-01-01); None
    when the file does not exist yet. Anything else unreadable is a :class:`SigningKeyError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="ascii")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as err:
        raise SigningKeyError(f"signing timestamp file {p}: cannot read: {err}") from None
    try:
        value = int(text.strip())
    except ValueError:
        raise SigningKeyError(
            f"signing timestamp file {p}: {text.strip()[:40]!r} is not an integer "
            "(expected the signing timestamp in 10 us units since 2015-01-01)"
        ) from None
    if not 0 <= value <= TIMESTAMP_MAX:
        raise SigningKeyError(f"signing timestamp file {p}: {value} is outside 0..2^48-1")
    return value


def write_timestamp_file(path: str | Path, timestamp: int) -> None:
    """Keep ``timestamp`` in ``path`` (written to a temporary file, then renamed: never half a number)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    try:
        tmp.write_text(f"{int(timestamp)}\n", encoding="ascii")
        os.replace(tmp, p)
    except OSError as err:
        raise SigningKeyError(f"signing timestamp file {p}: cannot write: {err.strerror}") from None


def accept_unsigned_ardupilot(_mav: Any, msg_id: int) -> bool:
    """ArduPilot's accept_unsigned_callback off channel 0: only the radios' own messages."""
    return msg_id in ACCEPT_UNSIGNED_IDS


def accept_everything(_mav: Any, _msg_id: int) -> bool:
    return True


def apply_to_mavlink(mav: Any, setup: SigningSetup, initial_timestamp: int | None = None) -> None:
    """Sign outgoing packets and check incoming ones on a pymavlink ``MAVLink`` object (``conn.mav``).
    With ``allow_unsigned`` every unsigned or wrongly signed packet is still accepted (sign
    outgoing only); otherwise only RADIO_STATUS / RADIO are, as on ArduPilot."""
    signing = mav.signing
    signing.secret_key = setup.key.secret
    signing.link_id = setup.link_id
    signing.sign_outgoing = True
    signing.allow_unsigned_callback = accept_everything if setup.allow_unsigned else accept_unsigned_ardupilot
    if initial_timestamp is None:
        initial_timestamp = setup.initial_timestamp()
    signing.timestamp = max(int(signing.timestamp or 0), initial_timestamp)
    _note_times_of_signed_packets_only(mav)


def _note_times_of_signed_packets_only(mav: Any) -> None:
    """pymavlink's ``check_signature`` notes a stream's timestamp before it checks the signature, so
    one forged packet with a far-future timestamp under the autopilot's ids would make every later
    genuine packet of that stream look replayed (all telemetry refused: a link loss bought with one
    datagram). ArduPilot checks the signature first; so does this: a packet whose check fails
    leaves the stream's timestamp as it was."""
    if getattr(mav, "_times_of_signed_only", False):
        return
    check = mav.check_signature

    def check_then_note(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        stamps = mav.signing.stream_timestamps
        key = (msgbuf[-13], src_system, src_component)
        had, before = key in stamps, stamps.get(key)
        ok = bool(check(msgbuf, src_system, src_component))
        if not ok:
            if had:
                stamps[key] = before
            else:
                stamps.pop(key, None)
        return ok

    mav.check_signature = check_then_note
    mav._times_of_signed_only = True


def setup_signing_message(
    mav: Any, target_system: int, target_component: int, key: SigningKey | None, initial_timestamp: int
) -> Any:
    """SETUP_SIGNING for the vehicle; ``key`` None sends the all-zero key and timestamp 0 that
    turns ArduPilot's signing off."""
    secret = key.secret if key is not None else bytes(KEY_LEN)
    ts = initial_timestamp if key is not None else 0
    return mav.setup_signing_encode(target_system, target_component, list(secret), ts)
