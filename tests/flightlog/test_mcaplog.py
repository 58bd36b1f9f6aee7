"""``flight.mcap``: written beside the CSVs by the flight recorder, read back with mcap's own
reader (channels, schemas, counts, an image, the marker corners), and replay and report from a
run folder that holds only the MCAP."""

from __future__ import annotations

import csv
import io
import json
import math
import random
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from companion.delivery.replay import replay_run
from companion.flightlog.mcap_encoding import MCAP_FILE, batch_encoder, cell_text, encode_row, row_encoder, stream_topic
from companion.flightlog.reader import LogFormatError, open_table, read_mcap, read_meta
from companion.flightlog.streams import STREAM_FILES

pytestmark = pytest.mark.flight


def _csv_rows(path: Path) -> list[list[str]]:
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.reader(fh))


def _read(path: Path) -> tuple[dict[str, str], dict[str, list[bytes]], dict[str, str]]:
    """topic -> schema name, topic -> message payloads (in file order), metadata run.json."""
    schemas: dict[str, str] = {}
    payloads: dict[str, list[bytes]] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "companion"
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema is not None
            assert schema.encoding == "jsonschema"
            json.loads(schema.data)
            schemas[channel.topic] = schema.name
            payloads.setdefault(channel.topic, []).append(message.data)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    return schemas, payloads, meta["run.json"]


def test_the_mcap_holds_every_stream_the_csvs_hold(demo_run: Path) -> None:
    schemas, payloads, run_meta = _read(demo_run / MCAP_FILE)
    meta = json.loads(run_meta["json"])
    assert meta == json.loads((demo_run / "run.json").read_text()) and meta["mcap"] == MCAP_FILE
    for name, cols in STREAM_FILES.items():
        rows = _csv_rows(demo_run / name)
        assert rows[0] == list(cols)
        msgs = payloads.get(stream_topic(name), [])
        assert len(msgs) == len(rows) - 1 == meta["rows"][name], name
        if msgs:
            assert schemas[stream_topic(name)] == f"companion.{name.removesuffix('.csv')}"
            # every cell, as the CSV's text
            decoded = [[cell_text(json.loads(m)[c]) for c in cols] for m in msgs]
            assert decoded == rows[1:], name
    assert len(payloads["/log/camera"]) > 20 and len(payloads["/log/ekf"]) > 500  # a fused landing


def test_the_mcap_has_images_corners_pose_and_path_for_foxglove(demo_run: Path) -> None:
    schemas, payloads, _ = _read(demo_run / MCAP_FILE)
    assert schemas["/camera/image"] == "foxglove.CompressedImage"
    assert schemas["/camera/markers"] == "foxglove.ImageAnnotations"
    assert schemas["/ekf/pose"] == "foxglove.PoseInFrame"
    assert schemas["/mission/path"] == "foxglove.SceneUpdate"
    assert schemas["/tf"] == "foxglove.FrameTransform"
    n_cam = len(payloads["/log/camera"])
    assert len(payloads["/camera/image"]) == len(payloads["/camera/markers"]) == n_cam
    cam_times = [json.loads(m)["time_s"] for m in payloads["/log/camera"]]

    img = json.loads(payloads["/camera/image"][n_cam // 2])
    assert img["format"] == "jpeg" and img["frame_id"] == "camera"
    stamp = img["timestamp"]["sec"] + img["timestamp"]["nsec"] * 1e-9
    assert stamp == pytest.approx(cam_times[n_cam // 2], abs=1e-9)  # the exposure time of that observation
    import base64

    pixels = cv2.imdecode(np.frombuffer(base64.b64decode(img["data"]), np.uint8), cv2.IMREAD_UNCHANGED)
    assert pixels is not None and pixels.ndim in (2, 3) and pixels.shape[0] > 100 and pixels.shape[1] > 100
    assert float(pixels.std()) > 5.0  # a rendered scene, not a blank frame

    ann = json.loads(payloads["/camera/markers"][n_cam // 2])
    assert ann["points"], "no marker corners"
    markers = json.loads(payloads["/log/camera"][n_cam // 2])["markers"].split()
    assert sorted(t["text"] for t in ann["texts"]) == sorted(markers)
    h, w = pixels.shape[:2]
    for p in ann["points"]:
        assert p["type"] == 2 and len(p["points"]) == 4  # a LINE_LOOP round the marker's corners
        assert all(0 <= q["x"] <= w and 0 <= q["y"] <= h for q in p["points"])

    ekf = [json.loads(m) for m in payloads["/log/ekf"]]
    poses = [json.loads(m) for m in payloads["/ekf/pose"]]
    assert len(poses) == len(ekf) == len(payloads["/ekf/sigma"])
    k = len(ekf) // 2
    pos = poses[k]["pose"]["position"]
    assert (pos["x"], pos["y"], pos["z"]) == (ekf[k]["north_m"], ekf[k]["east_m"], ekf[k]["down_m"])
    q = poses[k]["pose"]["orientation"]
    assert math.isclose(q["x"] ** 2 + q["y"] ** 2 + q["z"] ** 2 + q["w"] ** 2, 1.0, rel_tol=1e-12)
    yaw = math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]), 1 - 2 * (q["y"] ** 2 + q["z"] ** 2))
    assert yaw == pytest.approx(ekf[k]["yaw_rad"], abs=1e-9)
    sigma = json.loads(payloads["/ekf/sigma"][k])
    assert sigma["sigma_north_m"] == pytest.approx(math.sqrt(ekf[k]["var_north_m2"]))

    path = json.loads(payloads["/mission/path"][0])
    line = path["entities"][0]["lines"][0]
    assert path["entities"][0]["frame_id"] == "ned" and len(line["points"]) > 50
    meta = json.loads((demo_run / "run.json").read_text())
    pad = meta["mission"]["pad_ned_m"]
    end = line["points"][-1]
    assert (end["x"], end["y"], end["z"]) == pytest.approx(tuple(pad), abs=1e-9)  # the path ends on the pad


def test_replay_from_an_mcap_only_folder_equals_replay_from_the_csvs(demo_run: Path, tmp_path: Path) -> None:
    only = tmp_path / "only"
    only.mkdir()
    shutil.copy(demo_run / MCAP_FILE, only / MCAP_FILE)
    from_csv = replay_run(demo_run, tmp_path / "from_csv")
    from_mcap = replay_run(only, tmp_path / "from_mcap")
    assert from_csv.identical and from_mcap.identical, "\n".join(from_mcap.lines())
    assert from_mcap.ticks == from_csv.ticks > 500 and from_mcap.missing_seq == 0
    for name in ("ekf.csv", "guidance.csv", "events.csv"):
        assert (tmp_path / "from_mcap" / name).read_text() == (tmp_path / "from_csv" / name).read_text()
        assert (tmp_path / "from_mcap" / name).read_text() == (demo_run / name).read_text()
    # an empty stream (no operator commands in the demo) comes from run.json's columns
    assert len(open_table(only, "commands.csv")) == 0
    assert read_meta(only)["rows"] == read_meta(demo_run)["rows"]


def test_report_from_an_mcap_only_folder(demo_run: Path, tmp_path: Path) -> None:
    from companion.flightlog.report import make_report

    only = tmp_path / "only"
    only.mkdir()
    shutil.copy(demo_run / MCAP_FILE, only / MCAP_FILE)
    written = {f.name for f in make_report(only, tmp_path / "png") if f.path is not None}
    assert {"path.png", "lyapunov.png", "landing_3d.png", "landing_axes.png", "gps_bias.png"} <= written, written


def test_a_torn_mcap_reads_up_to_the_tear(demo_run: Path, tmp_path: Path) -> None:
    """A hard crash leaves no summary and a cut last record: the chunks before it read back."""
    data = (demo_run / MCAP_FILE).read_bytes()
    torn = tmp_path / MCAP_FILE
    torn.write_bytes(data[: len(data) * 2 // 3])
    m = read_mcap(torn)
    assert m.torn
    for name, rows in m.streams.items():
        full = _csv_rows(demo_run / name)
        assert rows == full[: len(rows)], name  # a prefix of the CSV, cell for cell
    assert 0 < sum(len(r) - 1 for r in m.streams.values()) < sum(read_meta(demo_run)["rows"].values())


def test_bad_mcap_files_are_reported_by_name(tmp_path: Path) -> None:
    p = tmp_path / MCAP_FILE
    p.write_bytes(b"not an mcap at all")
    with pytest.raises(LogFormatError, match=rf"{MCAP_FILE}: .*not an MCAP file"):
        read_mcap(p)
    with pytest.raises(LogFormatError, match=r"missing\.mcap: file not found"):
        read_mcap(tmp_path / "missing.mcap")
    with pytest.raises(LogFormatError, match=r"run\.json: file not found \(nor flight\.mcap\)"):
        read_meta(tmp_path / "empty")


def test_an_mcap_from_another_tool_is_refused(tmp_path: Path) -> None:
    from mcap.writer import Writer

    p = tmp_path / MCAP_FILE
    with p.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        w.finish()
    with pytest.raises(LogFormatError, match=r"MCAP profile 'ros2', expected 'companion'"):
        read_mcap(p)


def test_row_encoding_is_lossless_and_both_encoders_agree() -> None:
    rng = random.Random(7)
    cols = ("time_s", "seq", "a_m", "b_m", "text")
    specials = [math.nan, math.inf, -math.inf, -0.0, 5e-324, 1.7976931348623157e308, 0.1 + 0.2]
    for k in range(2000):
        v = rng.choice(specials) if k % 7 == 0 else rng.uniform(-1e6, 1e6) * 10 ** rng.randint(-12, 12)
        text = rng.choice(["", "outer inner", "q\"uo'te", "ü,\n"])
        row: tuple[object, ...] = (float(k) * 0.01, k, v, np.float64(v) if k % 3 else v, text)
        numeric = row[:4]
        enc = row_encoder(cols)
        assert enc(row) == encode_row(cols, row)
        assert row_encoder(cols[:4])(numeric) == encode_row(cols[:4], numeric)
        obj = json.loads(enc(row))
        # the text a decoded cell gives is the text the CSV writer writes (str of the value)
        assert [cell_text(obj[c]) for c in cols] == [str(x) for x in row]


def _reference(cols: tuple[str, ...], batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]]:
    """What the CSV writer and the row-by-row JSON encoder give for a batch."""
    buf = io.StringIO()
    csv.writer(buf).writerows(batch)
    return buf.getvalue(), [encode_row(cols, row) for row in batch]


_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**70), 2**70),
    st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 0.0, 5e-324, 1e16, 0.1 + 0.2]),
    st.floats(allow_nan=True, allow_infinity=True).map(np.float64),
    st.booleans(),
    st.none(),
)
_PLAIN_NUMBERS = st.one_of(
    st.floats(-1e9, 1e9),
    st.integers(-(10**6), 10**6),
    st.sampled_from([math.nan, math.inf, -math.inf, -0.0]),
)
_PLAIN_TEXTS = st.sampled_from(["", "outbound", "a b", "nan", "-inf", "x:nan", "x:nan}", "{}", ":inf"])
_TEXTS = st.one_of(
    st.sampled_from(["", "outbound", "offboard", "a b", "nan", "inf", "-inf", "1.5", ":nan,", "x}"]),
    st.text(max_size=8),  # quotes, commas, backslashes, line ends, non-ASCII
    st.none(),
    st.integers(0, 9),
)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(st.data())
def test_the_batch_encoder_gives_the_csv_writers_text_and_the_row_encoders_messages(data: st.DataObject) -> None:
    """Whatever a batch holds (NaN, infinities, -0.0, big ints, numpy floats, flags as bools,
    None, text with quotes, commas, backslashes, line ends or non-ASCII, numbers in text
    columns), the batch encoder's CSV text and messages are csv.writer's and encode_row's."""
    cols = ("time_s", "seq", "phase", "a_m", "detail", "b_m")
    kinds = ["n", "n", "t", "n", "t", "n"]
    plain = data.draw(st.booleans())  # plain cells only: the batch-at-once paths
    numbers = _PLAIN_NUMBERS if plain else _NUMBERS
    texts = _PLAIN_TEXTS if plain else _TEXTS
    n_rows = data.draw(st.integers(1, 6))
    rows = [tuple(data.draw(numbers if kind == "n" else texts) for kind in kinds) for _ in range(n_rows)]
    assert batch_encoder(cols)(rows) == _reference(cols, rows)
    numeric_cols = ("time_s", "seq", "a_m")
    numeric_rows = [(r[0], r[1], r[3]) for r in rows]
    assert batch_encoder(numeric_cols)(numeric_rows) == _reference(numeric_cols, numeric_rows)


def test_the_batch_encoder_takes_whole_batches_with_non_finite_numbers_and_odd_rows() -> None:
    cols = ("time_s", "seq", "phase", "x_m", "request")
    batches: list[list[tuple[object, ...]]] = [
        [(0.5, 1, "outbound", math.nan, ""), (1.0, 2, "inbound", -math.inf, "land")],
        [(0.5, 1, "outbound", 0.25, "")],
        [(0.5, 1, 'say "hi"', 1.0, "a,b")],
        [(0.5, 1, "outbound", np.float64(0.1), "")],
        [(0.5, 1, None, True, "ü")],
        [],
    ]
    for batch in batches:
        assert batch_encoder(cols)(batch) == _reference(cols, batch)
    numeric = ("time_s", "x_m")
    for batch2 in ([(0.5, math.nan), (1.0, 2.0)], [(0.5, 1e300), (1, -0.0)]):
        assert batch_encoder(numeric)(batch2) == _reference(numeric, batch2)
    for short in ([(0.5, 1, "outbound", 0.25)], [(0.5,)]):  # a row of another length: as encode_row, refused
        with pytest.raises(ValueError):
            batch_encoder(cols if len(short[0]) == 4 else numeric)(short)
        with pytest.raises(ValueError):
            encode_row(cols if len(short[0]) == 4 else numeric, short[0])
