"""Experiment tooling (installed as ``companion_lab``): the demo runner, the landing and Dart
campaigns, sim-to-real parity, the firmware probe and every bench. It drives the application on the
embedded simulator (``companion_sitl``) or the real firmware (``companion_firmware``)."""
