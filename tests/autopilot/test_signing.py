"""Signing key files, timestamps and the [signing] section (no link)."""

from __future__ import annotations

import hashlib
import os
import random
import time

import pytest

from companion.autopilot.signing import (
    KEY_LEN,
    SigningKey,
    SigningKeyError,
    SigningSetup,
    apply_to_mavlink,
    generate_key,
    generate_passphrase,
    passphrase_key,
    read_key_file,
    read_timestamp_file,
    timestamp_from_unix,
    write_key_file,
    write_timestamp_file,
)
from companion.config import ConfigError, config_from_dict
from companion.secret_files import SecretFileExposed

RNG = random.Random(32)
SECRET = bytes(RNG.randrange(256) for _ in range(KEY_LEN))


def _file(tmp_path, data: bytes, name: str = "key"):
    p = tmp_path / name
    p.write_bytes(data)
    p.chmod(0o600)
    return p


def test_hex_raw_and_passphrase_files_give_the_same_kind_of_key(tmp_path):
    hexfile = _file(tmp_path, (SECRET.hex().upper()[:32] + "\n  " + SECRET.hex()[32:] + "\r\n").encode(), "k.hex")
    assert read_key_file(hexfile).secret == SECRET  # whitespace, case and CRLF do not matter
    assert read_key_file(hexfile, "hex").secret == SECRET
    raw = _file(tmp_path, SECRET, "k.bin")
    assert read_key_file(raw).secret == SECRET and read_key_file(raw, "raw").source == str(raw)
    # MAVProxy `signing setup PASSPHRASE`: SHA-256 of the passphrase
    phrase = _file(tmp_path, b"correct-horse-battery\n", "k.txt")
    expected = hashlib.sha256(b"correct-horse-battery").digest()
    assert read_key_file(phrase, "passphrase").secret == expected == passphrase_key("correct-horse-battery").secret


def test_a_32_byte_file_of_hex_digits_is_raw_only_when_it_cannot_be_hex(tmp_path):
    looks_hex = _file(tmp_path, b"0123456789abcdef" * 2)  # 32 hex digits = 32 raw bytes
    assert read_key_file(looks_hex).secret == b"0123456789abcdef" * 2
    with pytest.raises(SigningKeyError, match=r"expected 64 hexadecimal digits .* got 32 characters"):
        read_key_file(looks_hex, "hex")


@pytest.mark.parametrize(
    ("data", "fmt", "message"),
    [
        (b"", "auto", r"empty; expected 64 hex digits or 32 bytes"),
        (SECRET[:31], "auto", r"31 bytes is not a signing key: expected 64 hexadecimal digits or exactly 32 raw"),
        (SECRET[:31], "raw", r"a raw key file is exactly 32 bytes, got 31"),
        (SECRET.hex()[:62].encode(), "hex", r"expected 64 hexadecimal digits \(a 32-byte key\), got 62 characters"),
        (("g" + SECRET.hex()[1:]).encode(), "hex", r"'g' is not a hexadecimal digit"),
        (b"my passphrase\n", "auto", r"needs signing.key_format = 'passphrase'"),
        (b"one\ntwo\n", "passphrase", r"a passphrase file holds one line, found 2"),
        (b"\n", "passphrase", r"the passphrase is empty"),
        (b"\xff\xfe" * 20, "hex", r"not UTF-8 text .* expected a hex key"),
    ],
)
def test_bad_key_files_name_the_file_and_what_is_expected(tmp_path, data, fmt, message):
    p = _file(tmp_path, data, "bad.key")
    with pytest.raises(SigningKeyError, match=message) as err:
        read_key_file(p, fmt)
    assert str(p) in str(err.value)


def test_missing_directory_and_unreadable_key_files(tmp_path):
    with pytest.raises(SigningKeyError, match=r"nope.key: not found \(make one with `companion signing keygen"):
        read_key_file(tmp_path / "nope.key")
    with pytest.raises(SigningKeyError, match=r"is a directory, expected a file"):
        read_key_file(tmp_path)
    if os.geteuid() != 0:  # root reads anything
        p = _file(tmp_path, SECRET)
        p.chmod(0)
        with pytest.raises(SigningKeyError, match=r"cannot read: Permission denied"):
            read_key_file(p)


@pytest.mark.parametrize("mode", [0o640, 0o620, 0o604, 0o602, 0o644, 0o666, 0o777])
def test_a_key_file_group_or_others_can_read_or_write_is_refused(tmp_path, mode):
    p = _file(tmp_path, SECRET.hex().encode())
    p.chmod(mode)
    with pytest.raises(SigningKeyError) as err:
        read_key_file(p)
    assert str(err.value).startswith(f"signing key file {p}: mode {mode:04o}: ")
    assert str(err.value).endswith(f"run `chmod 600 {p}`")
    assert isinstance(err.value.__cause__, SecretFileExposed) and err.value.__cause__.mode == mode


@pytest.mark.parametrize("mode", [0o600, 0o400, 0o700, 0o611])
def test_a_key_file_only_its_owner_can_read_or_write_is_read(tmp_path, mode):
    p = _file(tmp_path, SECRET.hex().encode())
    p.chmod(mode)  # execute bits expose nothing
    assert read_key_file(p).secret == SECRET


def test_keygen_writes_a_private_hex_file_and_never_replaces_one(tmp_path):
    key = generate_key()
    p = write_key_file(tmp_path / "new.key", key)
    assert (p.stat().st_mode & 0o777) == 0o600 and p.read_text() == key.hex + "\n"
    assert read_key_file(p).secret == key.secret and key.secret != generate_key().secret
    with pytest.raises(SigningKeyError, match=r"exists; refusing to replace a key \(pass --force\)"):
        write_key_file(p, generate_key())
    other = generate_key()
    write_key_file(p, other, overwrite=True)
    assert read_key_file(p).secret == other.secret
    phrase = generate_passphrase()
    assert len(phrase) == 40 and " " not in phrase
    q = write_key_file(tmp_path / "phrase.key", phrase)
    assert read_key_file(q, "passphrase").secret == hashlib.sha256(phrase.encode()).digest()


def test_the_key_is_never_in_its_repr_and_has_a_fingerprint():
    key = SigningKey(SECRET, "k")
    assert SECRET.hex() not in repr(key) and key.fingerprint in repr(key)
    assert key.fingerprint == hashlib.sha256(SECRET).hexdigest()[:8]
    with pytest.raises(SigningKeyError, match="a signing key is 32 bytes, got 5"):
        SigningKey(b"short", "k")
    with pytest.raises(SigningKeyError, match=r"signing.link_id = 256: must be 0..255"):
        SigningSetup(key, link_id=256)


def test_signing_timestamps_count_10_us_since_2015():
    assert timestamp_from_unix(1420070400.0) == 0
    assert timestamp_from_unix(1420070401.5) == 150_000
    assert timestamp_from_unix(0.0) == 0  # before the epoch: 0
    assert timestamp_from_unix(1.0e12) == (1 << 48) - 1


def test_apply_to_mavlink_signs_and_never_turns_the_timestamp_back():
    os.environ["MAVLINK20"] = "1"
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=191)
    mav.signing.timestamp = 5_000
    apply_to_mavlink(mav, SigningSetup(SigningKey(SECRET, "k"), link_id=3), initial_timestamp=100)
    assert mav.signing.timestamp == 5_000 and mav.signing.link_id == 3 and mav.signing.sign_outgoing
    assert mav.signing.allow_unsigned_callback(mav, 109) and not mav.signing.allow_unsigned_callback(mav, 0)
    apply_to_mavlink(mav, SigningSetup(SigningKey(SECRET, "k"), allow_unsigned=True), initial_timestamp=9_000)
    assert mav.signing.timestamp == 9_000 and mav.signing.allow_unsigned_callback(mav, 0)


def test_a_forged_far_future_packet_does_not_lock_out_the_stream_it_names():
    """One packet under the autopilot's ids (1/1) with a timestamp far ahead and a wrong signature
    is refused and leaves that stream's timestamp as it was: the autopilot's next genuine packet is
    still taken (pymavlink alone noted the forged time first, and refused every genuine packet
    after it as replayed)."""
    os.environ["MAVLINK20"] = "1"
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    key, t0 = SigningKey(SECRET, "k"), 400_000_000_000

    def sender(secret: bytes, timestamp: int):
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        mav.signing.secret_key, mav.signing.link_id, mav.signing.sign_outgoing = secret, 0, True
        mav.signing.timestamp = timestamp
        return mav

    def heartbeat(mav) -> bytes:
        return mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mav)

    rx = mavlink.MAVLink(None)
    rx.robust_parsing = True
    apply_to_mavlink(rx, SigningSetup(key, allow_unsigned=False), initial_timestamp=t0)
    genuine, forger = sender(SECRET, t0 + 10), sender(bytes(32), t0 + 10**12)
    got = [m.get_type() for m in rx.parse_buffer(heartbeat(genuine) + heartbeat(forger) + heartbeat(genuine)) or []]
    assert got == ["HEARTBEAT", "BAD_DATA", "HEARTBEAT"], got
    assert rx.signing.stream_timestamps[(0, 1, 1)] < t0 + 10**6  # the forged time never noted
    apply_to_mavlink(rx, SigningSetup(key, allow_unsigned=False), initial_timestamp=t0)  # applied twice: wrapped once
    assert [m.get_type() for m in rx.parse_buffer(heartbeat(genuine)) or []] == ["HEARTBEAT"]


def test_signing_section_rules():
    with pytest.raises(ConfigError, match=r"signing.enabled needs signing.key_file"):
        config_from_dict({"signing": {"enabled": True}})
    with pytest.raises(ConfigError, match=r"signing.link_id = 300: Input should be less than or equal to 255"):
        config_from_dict({"signing": {"link_id": 300}})
    with pytest.raises(ConfigError, match=r"signing.key_format = 'base64'"):
        config_from_dict({"signing": {"key_format": "base64"}})
    cfg = config_from_dict({"autopilot": "ardupilot", "signing": {"enabled": True, "key_file": "k.hex"}})
    assert cfg.signing.link_id == 1 and not cfg.signing.allow_unsigned and cfg.signing.timestamp_file is None


def test_the_timestamp_file_keeps_our_timestamp_and_names_bad_contents(tmp_path):
    f = tmp_path / "signing.ts"
    assert read_timestamp_file(f) is None  # not there yet: the clock alone
    key = SigningKey(SECRET, "k")
    now = SigningSetup(key, timestamp_file=f).initial_timestamp()
    assert abs(now - timestamp_from_unix(time.time())) < 10 * 100_000
    ahead = now + 3600 * 100_000
    write_timestamp_file(f, ahead)
    assert read_timestamp_file(f) == ahead and not (tmp_path / "signing.ts.tmp").exists()
    assert SigningSetup(key, timestamp_file=f).initial_timestamp() == ahead + 60 * 100_000  # as ArduPilot
    write_timestamp_file(f, 5)  # far behind the clock: the clock wins
    assert abs(SigningSetup(key, timestamp_file=f).initial_timestamp() - now) < 10 * 100_000
    f.write_text("12ab\n")
    with pytest.raises(SigningKeyError, match=r"signing.ts: '12ab' is not an integer \(expected the signing timestamp"):
        read_timestamp_file(f)
    f.write_text(str(1 << 48))
    with pytest.raises(SigningKeyError, match=r"281474976710656 is outside 0..2\^48-1"):
        read_timestamp_file(f)
    with pytest.raises(SigningKeyError, match=r"cannot write"):
        write_timestamp_file(tmp_path / "no" / "dir" / "ts", 1)
