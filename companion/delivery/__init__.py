"""The delivery application (delivery paper): fly a parcel along a planned path, land on the pad,
release, fly home.

- :mod:`.mission`        the mission state machine (phases, sectors, aborts), pure and synchronous
- :mod:`.planning`       the path from the configured waypoints
- :mod:`.fusion`         GPS + camera + UWB landing fusion in the EKF; :mod:`.passthrough` the GPS-only baseline
- :mod:`.landing_setup`  the landing kit: camera, pad detector, UWB anchors from the parameters
- :mod:`.shell`          the asyncio shell: autopilot, sensors, rates, the safety contract
- :mod:`.telemetry`      the shell's adapter to the Zenoh telemetry publisher
- :mod:`.replay`         re-run the core over a recorded run folder, bit for bit
"""
