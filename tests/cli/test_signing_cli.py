"""`companion signing keygen / show / push` and `companion fly` with a bad signing key file."""

from __future__ import annotations

import hashlib
import socket
import subprocess
import sys

from companion.autopilot.signing import read_key_file
from companion.cli import exits
from companion.cli.main import main
from companion.config import shipped_params_path
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.params import load_simulated_config


def test_keygen_writes_a_key_show_reads_it_and_keygen_never_replaces_it(tmp_path, capsys):
    key_file = tmp_path / "link.key"
    assert main(["signing", "keygen", str(key_file)]) == exits.OK
    out = capsys.readouterr().out
    key = read_key_file(key_file)
    assert f"fingerprint {key.fingerprint}" in out and key.hex not in out  # the secret is not printed
    assert f"companion signing show --hex {key_file}" in out
    assert f"key_file = '{key_file}'" in out and (key_file.stat().st_mode & 0o777) == 0o600
    assert main(["signing", "keygen", str(key_file)]) == exits.BAD_INPUT
    assert "exists; refusing to replace a key (pass --force)" in capsys.readouterr().err
    assert read_key_file(key_file) == key
    assert main(["signing", "show", str(key_file)]) == exits.OK
    out = capsys.readouterr().out
    assert key.fingerprint in out and key.hex not in out  # the secret only with --hex
    assert main(["signing", "show", "--hex", str(key_file)]) == exits.OK
    assert key.hex in capsys.readouterr().out


def test_keygen_passphrase_prints_the_mavproxy_command_for_the_same_secret(tmp_path, capsys):
    key_file = tmp_path / "phrase.key"
    assert main(["signing", "keygen", "--passphrase", str(key_file)]) == exits.OK
    out = capsys.readouterr().out
    phrase = key_file.read_text().strip()
    assert f'MAVProxy (same secret): signing setup "$(cat {key_file})"' in out and "key_format = 'passphrase'" in out
    assert phrase not in out and hashlib.sha256(phrase.encode()).hexdigest() not in out  # neither the secret
    # read as a key it is no key, and the hint names this command's option, not a parameter-file key
    assert main(["signing", "show", str(key_file)]) == exits.BAD_INPUT
    assert "a passphrase file needs --format passphrase" in capsys.readouterr().err
    assert main(["signing", "show", "--format", "passphrase", "--hex", str(key_file)]) == exits.OK
    assert hashlib.sha256(phrase.encode()).hexdigest() in capsys.readouterr().out


def test_show_names_the_file_and_what_is_expected(tmp_path, capsys):
    bad = tmp_path / "short.key"
    bad.write_bytes(b"\x01" * 31)
    bad.chmod(0o600)
    assert main(["signing", "show", str(bad)]) == exits.BAD_INPUT
    err = capsys.readouterr().err
    assert f"companion signing: {bad}: 31 bytes is not a signing key: expected 64 hexadecimal digits" in err
    bad.chmod(0o644)  # a key file others can read is refused before its contents are looked at
    assert main(["signing", "show", str(bad)]) == exits.BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"signing key file {bad}: mode 0644: group can read it, others can read it;" in err
    assert err.endswith(f"run `chmod 600 {bad}`\n")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_push_gives_the_sim_vehicle_the_key_and_off_takes_it_away(tmp_path, capsys):
    key_file = tmp_path / "link.key"
    assert main(["signing", "keygen", str(key_file)]) == exits.OK
    key = read_key_file(key_file)
    params = tmp_path / "vehicle.toml"
    params.write_text(f'autopilot = "ardupilot"\n[signing]\nkey_file = "{key_file}"\n')
    port = _free_udp_port()
    cfg = load_simulated_config(shipped_params_path("sitl_short.toml"))
    sim = mavlink_sim_vehicle(cfg.sim, "ardupilot", remote=("127.0.0.1", port)).start()
    try:
        args = ["signing", "push", "--params", str(params), "--connection", f"udpin:127.0.0.1:{port}"]
        assert main([*args, "--timeout", "5"]) == exits.OK
        assert f"the vehicle signs with key {key.fingerprint}" in capsys.readouterr().out
        assert sim.signing_key == key.secret
        assert main([*args, "--off", "--timeout", "5"]) == exits.OK  # signed with our key, as it must be now
        assert sim.signing_key is None
    finally:
        sim.stop()


def test_push_to_a_vehicle_signing_with_another_key_fails_naming_it(tmp_path, capsys):
    key_file = tmp_path / "link.key"
    assert main(["signing", "keygen", str(key_file)]) == exits.OK
    params = tmp_path / "vehicle.toml"
    params.write_text(f'autopilot = "ardupilot"\n[signing]\nkey_file = "{key_file}"\n')
    port = _free_udp_port()
    cfg = load_simulated_config(shipped_params_path("sitl_short.toml"))
    other = hashlib.sha256(b"someone else's key").digest()
    sim = mavlink_sim_vehicle(cfg.sim, "ardupilot", remote=("127.0.0.1", port), signing_key=other).start()
    try:
        args = ["signing", "push", "--params", str(params), "--connection", f"udpin:127.0.0.1:{port}"]
        assert main([*args, "--timeout", "3"]) == exits.FAILED
        assert "the vehicle did not start signing with key" in capsys.readouterr().err
        assert sim.signing_key == other
    finally:
        sim.stop()


def test_fly_with_a_missing_key_file_is_bad_input(tmp_path):
    params = tmp_path / "vehicle.toml"
    params.write_text(
        'autopilot = "ardupilot"\nconnection = "udpin:127.0.0.1:1"\n'
        f'[signing]\nenabled = true\nkey_file = "{tmp_path / "nope.key"}"\n'
        "[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n[telemetry]\nenabled = false\n"
    )
    proc = subprocess.run(
        [sys.executable, "-m", "companion", "fly", "--params", str(params), "--out", str(tmp_path / "run")],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert proc.returncode == exits.BAD_INPUT, proc.stderr
    assert "nope.key: not found (make one with `companion signing keygen" in proc.stderr
    assert "fix signing.key_file in" in proc.stderr and "Traceback" not in proc.stderr


def test_bench_signing_reports_both_variants_from_one_run(capsys):
    assert main(["bench", "signing", "--n", "300", "--rounds", "1"]) == exits.OK
    out = capsys.readouterr().out
    assert "65 B unsigned, 78 B signed" in out  # the 13-byte signature block
    assert "us signed (x" in out and "us verified (x" in out


def test_dart_signing_key_errors_stop_before_anything_starts(tmp_path, capsys):
    dart_params = str(shipped_params_path("dart_hover.toml"))
    missing = tmp_path / "nope.key"
    assert main(["dart", "--params", dart_params, "--signing-key", str(missing)]) == exits.BAD_INPUT
    assert f"companion dart: --signing-key: signing key file {missing}: not found" in capsys.readouterr().err
    assert main(["dart", "--params", dart_params, "--autopilot", "px4", "--signing-key", str(missing)]) == 2
    assert "the PX4 backend cannot sign" in capsys.readouterr().err
    assert main(["dart", "--sim", "ardupilot", "--signing-key", str(missing)]) == 2
    assert "--sim flies unsigned" in capsys.readouterr().err


def test_fly_against_a_vehicle_that_does_not_sign_stops_naming_signing(tmp_path):
    key_file = tmp_path / "link.key"
    assert main(["signing", "keygen", str(key_file)]) == exits.OK
    port = _free_udp_port()
    params = tmp_path / "vehicle.toml"
    params.write_text(
        f'autopilot = "ardupilot"\nconnection = "udpin:127.0.0.1:{port}"\n'
        f'[signing]\nenabled = true\nkey_file = "{key_file}"\n[runtime]\nconnect_timeout_s = 2.0\n'
        "[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n[telemetry]\nenabled = false\n"
    )
    cfg = load_simulated_config(shipped_params_path("sitl_short.toml"))
    sim = mavlink_sim_vehicle(cfg.sim, "ardupilot", remote=("127.0.0.1", port)).start()
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "fly", "--params", str(params), "--out", str(tmp_path / "run")],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=tmp_path,
        )
    finally:
        sim.stop()
    assert proc.returncode == exits.AUTOPILOT_UNREACHABLE, proc.stderr
    assert "MAVLink signing refused" in proc.stderr and "companion signing push" in proc.stderr
    assert "Traceback" not in proc.stderr and not sim.vehicle.armed


def test_fly_with_a_key_file_others_can_read_stops_before_the_link_opens(tmp_path, capsys):
    key_file = tmp_path / "link.key"
    assert main(["signing", "keygen", str(key_file)]) == exits.OK
    key_file.chmod(0o640)
    params = tmp_path / "vehicle.toml"
    params.write_text(
        f'autopilot = "ardupilot"\nconnection = "udpin:127.0.0.1:1"\n[signing]\nenabled = true\n'
        f'key_file = "{key_file}"\n'
    )
    capsys.readouterr()
    assert main(["fly", "--params", str(params), "--out", str(tmp_path / "run")]) == exits.BAD_INPUT
    err = capsys.readouterr().err
    assert err == (
        f"companion fly: signing key file {key_file}: mode 0640: group can read it; a secret must be its owner's "
        f"only: run `chmod 600 {key_file}` (signing.key_file in {params})\n"
    )
    assert not (tmp_path / "run").exists()
