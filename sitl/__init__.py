"""Simulation (installed as ``companion_sitl``): vehicle dynamics, sensors, the embedded autopilot."""
