"""The Foxglove side shared by the flight log (``flightlog.mcap_file``) and the ground station's
live bridge (``telemetry.foxglove_bridge``): the well-known Foxglove JSON schemas of the message
types we write, time stamps, and the frame conventions (NED inside, ENU in Foxglove's 3D view).
A base module (no companion imports), so neither layer-4 package imports the other."""

from __future__ import annotations

import math
from typing import Any

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in ("x", "y", "z")}}
_VEC2 = {"type": "object", "properties": {k: {"type": "number"} for k in ("x", "y")}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in ("x", "y", "z", "w")}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
_COLOR = {"type": "object", "properties": {k: {"type": "number", "minimum": 0, "maximum": 1} for k in "rgba"}}

# The Foxglove JSON schemas of the message types used (https://docs.foxglove.dev/docs/sdk/schemas).
FOXGLOVE_SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CompressedImage": {
        "title": "foxglove.CompressedImage",
        "description": "A compressed image",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"},
            "format": {"type": "string"},
        },
    },
    "foxglove.ImageAnnotations": {
        "title": "foxglove.ImageAnnotations",
        "description": "Array of annotations for a 2D image",
        "type": "object",
        "properties": {
            "circles": {"type": "array", "items": {"type": "object"}},
            "points": {
                "type": "array",
                "items": {
                    "type": "object",
                    "title": "foxglove.PointsAnnotation",
                    "properties": {
                        "timestamp": _TIME,
                        "type": {
                            "title": "foxglove.PointsAnnotationType",
                            "type": "integer",
                            "oneOf": [
                                {"title": "UNKNOWN", "const": 0},
                                {"title": "POINTS", "const": 1},
                                {"title": "LINE_LOOP", "const": 2},
                                {"title": "LINE_STRIP", "const": 3},
                                {"title": "LINE_LIST", "const": 4},
                            ],
                        },
                        "points": {"type": "array", "items": _VEC2},
                        "outline_color": _COLOR,
                        "outline_colors": {"type": "array", "items": _COLOR},
                        "fill_color": _COLOR,
                        "thickness": {"type": "number"},
                    },
                },
            },
            "texts": {
                "type": "array",
                "items": {
                    "type": "object",
                    "title": "foxglove.TextAnnotation",
                    "properties": {
                        "timestamp": _TIME,
                        "position": _VEC2,
                        "text": {"type": "string"},
                        "font_size": {"type": "number"},
                        "text_color": _COLOR,
                        "background_color": _COLOR,
                    },
                },
            },
        },
    },
    "foxglove.PoseInFrame": {
        "title": "foxglove.PoseInFrame",
        "description": "A timestamped pose for an object or reference frame in 3D space",
        "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
    },
    "foxglove.LocationFix": {
        "title": "foxglove.LocationFix",
        "description": "A navigation satellite fix for any Global Navigation Satellite System",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "latitude": {"type": "number"},
            "longitude": {"type": "number"},
            "altitude": {"type": "number"},
            "position_covariance": {"type": "array", "items": {"type": "number"}, "minItems": 9, "maxItems": 9},
            "position_covariance_type": {
                "title": "foxglove.PositionCovarianceType",
                "type": "integer",
                "oneOf": [
                    {"title": "UNKNOWN", "const": 0},
                    {"title": "APPROXIMATED", "const": 1},
                    {"title": "DIAGONAL_KNOWN", "const": 2},
                    {"title": "KNOWN", "const": 3},
                ],
            },
        },
    },
    "foxglove.FrameTransform": {
        "title": "foxglove.FrameTransform",
        "description": "A transform between two reference frames in 3D space",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _VEC3,
            "rotation": _QUAT,
        },
    },
    "foxglove.SceneUpdate": {
        "title": "foxglove.SceneUpdate",
        "description": "An update to the entities displayed in a 3D scene",
        "type": "object",
        "properties": {
            "deletions": {"type": "array", "items": {"type": "object"}},
            "entities": {
                "type": "array",
                "items": {
                    "type": "object",
                    "title": "foxglove.SceneEntity",
                    "properties": {
                        "timestamp": _TIME,
                        "frame_id": {"type": "string"},
                        "id": {"type": "string"},
                        "lifetime": _TIME,
                        "frame_locked": {"type": "boolean"},
                        "metadata": {"type": "array", "items": {"type": "object"}},
                        "lines": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "title": "foxglove.LinePrimitive",
                                "properties": {
                                    "type": {
                                        "title": "foxglove.LineType",
                                        "type": "integer",
                                        "oneOf": [
                                            {"title": "LINE_STRIP", "const": 0},
                                            {"title": "LINE_LOOP", "const": 1},
                                            {"title": "LINE_LIST", "const": 2},
                                        ],
                                    },
                                    "pose": _POSE,
                                    "thickness": {"type": "number", "minimum": 0},
                                    "scale_invariant": {"type": "boolean"},
                                    "points": {"type": "array", "items": _VEC3},
                                    "color": _COLOR,
                                    "colors": {"type": "array", "items": _COLOR},
                                    "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                                },
                            },
                        },
                        "spheres": {"type": "array", "items": {"type": "object"}},
                    },
                },
            },
        },
    },
}

EKF_SIGMA_SCHEMA: dict[str, Any] = {
    "title": "companion.ekf_sigma",
    "description": "1-sigma of the EKF position (m) and attitude (deg), from the covariance diagonal",
    "type": "object",
    "properties": {
        "time_s": {"type": "number"},
        **{
            f"sigma_{a}_{u}": {"type": "number"}
            for a, u in (
                ("north", "m"),
                ("east", "m"),
                ("down", "m"),
                ("roll", "deg"),
                ("pitch", "deg"),
                ("yaw", "deg"),
            )
        },
    },
}

# world (ENU, z up: Foxglove's 3D view) -> ned: swap x/y, flip z (180 deg about (1, 1, 0)/sqrt 2)
ENU_FROM_NED_QUAT = {"x": math.sqrt(0.5), "y": math.sqrt(0.5), "z": 0.0, "w": 0.0}


def time_ns(t_s: float) -> int:
    """Seconds to the MCAP's unsigned nanoseconds (negative or non-finite times become 0)."""
    return round(t_s * 1e9) if math.isfinite(t_s) and t_s > 0.0 else 0


def foxglove_time(t_s: float) -> dict[str, int]:
    ns = time_ns(t_s)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def quat_from_euler_zyx(roll: float, pitch: float, yaw: float) -> dict[str, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return {
        "x": sr * cp * cy - cr * sp * sy,
        "y": cr * sp * cy + sr * cp * sy,
        "z": cr * cp * sy - sr * sp * cy,
        "w": cr * cp * cy + sr * sp * sy,
    }
