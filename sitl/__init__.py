"""The embedded simulator (installed as ``companion_sitl``): vehicle dynamics and autopilot profiles,
the in-process autopilot, the simulated camera and UWB, the MAVLink sim vehicle and the Dart
simulator, and scoring against their truth."""
