"""Real-firmware harnesses (installed as ``companion_firmware``): start and stop a built PX4 SIH or
ArduCopter SITL, read its ground truth, fly the companion against it with landing sensors rendered
from that truth, and cut its link. Never builds the firmware."""
