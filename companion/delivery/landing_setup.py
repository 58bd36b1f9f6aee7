"""The precision-landing kit of a real vehicle, from configuration: sensor plugins found through
entry points (``companion.cameras``, ``companion.uwb``), the camera calibration, the pad layout,
the UWB anchor layout and the camera mount. The simulator builds its own kit
(:func:`companion_sitl.landing_sensors.sim_landing_kit`); everything after the plugins is the same code.

A sensor that cannot be set up is an error naming the plugin, the setting and the reason, raised
before take-off, with the switch that flies without it (``use_camera`` / ``use_uwb`` /
``fusion``). A delivery never starts believing it has a camera that is not there.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from companion.config import CompanionConfig, ConfigError, shipped_params_path
from companion.delivery.shell import LandingKit
from companion.plugin_api import PluginError, create

log = logging.getLogger(__name__)


class LandingSetupError(RuntimeError):
    """A landing sensor or file could not be set up (the message says which and how to fly without).
    ``device_missing``: the device itself did not start (unplugged, wrong path), as opposed to a
    setting or file that is wrong."""

    def __init__(self, message: str, device_missing: bool = False) -> None:
        super().__init__(message)
        self.device_missing = device_missing


def resolve_params_file(name: str, key: str) -> Path:
    """``name`` as a path if it exists, else a file shipped in ``params/``."""
    p = Path(name).expanduser()
    if p.is_file():
        return p
    try:
        return shipped_params_path(name)
    except ConfigError as err:
        raise LandingSetupError(f"landing.{key} = {name!r}: no such file, and {err}") from None


def check_parcel_tag(config: CompanionConfig, layout: Any) -> None:
    """[winch.camera]'s tag must not be one of the pad's own markers (the detector would take the
    pad for the parcel): refused before take-off."""
    from companion.vision.parcel_tag import tag_clashes_with_pad

    wc = config.winch.camera
    if not wc.enabled:
        return
    clash = tag_clashes_with_pad(layout, wc.tag_dict, wc.tag_id)
    if clash:
        raise LandingSetupError(f"winch.camera: {clash}; choose another winch.camera.tag_dict or tag_id")


def build_landing_kit(config: CompanionConfig) -> LandingKit | None:
    """The kit for ``config.landing``, or None when fusion is off (GPS-only)."""
    from companion.geometry.mounts import downward_mount
    from companion.geometry.se3 import Transform
    from companion.uwb.anchors import AnchorLayoutError, load_anchor_layout
    from companion.uwb.multilateration import Multilaterator
    from companion.vision.camera import CameraConfigError, load_camera
    from companion.vision.detector import PadDetector
    from companion.vision.pad import PadConfigError, load_pad

    lc = config.landing
    if not lc.fusion:
        return None
    camera: Any = None
    uwb: Any = None
    detector = multi = None
    if lc.use_camera:
        try:
            model = load_camera(resolve_params_file(lc.camera_calibration, "camera_calibration"))
        except CameraConfigError as err:
            raise LandingSetupError(f"landing.camera_calibration = {lc.camera_calibration!r}: {err}") from None
        try:
            layout = load_pad(resolve_params_file(lc.pad_file, "pad_file"))
        except PadConfigError as err:
            raise LandingSetupError(f"landing.pad_file = {lc.pad_file!r}: {err}") from None
        markers = ("outer", "inner") if lc.markers == "both" else (lc.markers,)
        detector = PadDetector(model, layout, lc.detector, markers=markers)
        check_parcel_tag(config, layout)
        source: str | int = int(lc.camera_source) if lc.camera_source.isdigit() else lc.camera_source
        try:
            camera = create(
                "companion.cameras",
                lc.camera_plugin,
                source=source,
                width_px=model.width_px,
                height_px=model.height_px,
                fps=lc.camera_rate_hz,
                latency_s=lc.camera_latency_s,
                # the driver's capture stamps, asked for only when used (docs/clock.md): a plugin
                # without the option is told here, before take-off
                **({"driver_stamp": True} if lc.camera_time != "configured" else {}),
            )
        except (PluginError, TypeError) as err:
            raise LandingSetupError(
                f"camera plugin {lc.camera_plugin!r} (landing.camera_source = {lc.camera_source!r}): {err}; "
                "set landing.use_camera = false to fly without the camera"
            ) from err
    if lc.use_uwb:
        try:
            anchors = load_anchor_layout(resolve_params_file(lc.uwb_anchors, "uwb_anchors"))
        except AnchorLayoutError as err:
            raise LandingSetupError(f"landing.uwb_anchors = {lc.uwb_anchors!r}: {err}") from None
        multi = Multilaterator(anchors, lc.multilateration)
        try:
            uwb = create("companion.uwb", lc.uwb_plugin, port=lc.uwb_port)
        except (PluginError, TypeError) as err:
            raise LandingSetupError(
                f"UWB plugin {lc.uwb_plugin!r} (landing.uwb_port = {lc.uwb_port!r}): {err}; "
                "set landing.use_uwb = false to fly without UWB"
            ) from err
    if camera is None and uwb is None:
        raise LandingSetupError(
            "landing.fusion = true but both use_camera and use_uwb are false: nothing to fuse; "
            "set landing.fusion = false for a GPS-only landing"
        )
    return LandingKit(
        camera,
        uwb,
        detector,
        multi,
        downward_mount(lc.camera_offset_body_m),
        Transform.identity(),  # anchor coordinates are given in the pad frame
        vision_attitude=lc.vision_attitude,
    )


def record_camera(kit: LandingKit, video: Path, fps: float) -> LandingKit:
    """The kit with its camera recorded: every frame the flight reads is written to ``video`` and
    its exposure time (the shell's clock) to ``<video>.csv``, for ``companion demo --camera-file``."""
    import dataclasses

    from companion.flightlog.camera_file import CameraFileError, CameraFileWriter, RecordingCamera

    if kit.camera is None:
        raise LandingSetupError(f"--record-camera {video}: no camera to record (landing.use_camera = false)")
    try:
        writer = CameraFileWriter(video, fps=fps)
    except (CameraFileError, OSError) as err:
        raise LandingSetupError(f"--record-camera {video}: {err}") from None
    return dataclasses.replace(kit, camera=RecordingCamera(kit.camera, writer))


def start_sensors(kit: LandingKit) -> None:
    """Start the sensors on the ground, before take-off, so a missing device fails there; the
    shell then leaves them running and stops them when the flight ends."""
    started: list[Any] = []
    for name, dev in (("camera", kit.camera), ("uwb", kit.uwb)):
        if dev is None:
            continue
        try:
            dev.start()
        except Exception as err:
            for d in started:
                try:
                    d.stop()
                except Exception as stop_err:
                    log.debug("stop after a failed start: %s", stop_err)
            setting = "camera_source" if name == "camera" else "uwb_port"
            raise LandingSetupError(
                f"{name} {type(dev).__name__} does not start: {err}; check landing.{setting}, "
                f"or set landing.use_{name} = false to fly without it",
                device_missing=True,
            ) from err
        started.append(dev)
    kit.sensors_started = True
