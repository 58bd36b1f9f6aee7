"""The embedded :class:`~companion_sitl.vehicle.SimVehicle` served over real MAVLink 2 on UDP, in
real time (:class:`~companion_sitl.mavlink.vehicle.MavlinkSimVehicle`).

A background thread steps the vehicle on ``time.monotonic`` and speaks one of two dialects;
:func:`~companion_sitl.mavlink.factory.mavlink_sim_vehicle` builds the one named:

- ``"px4"`` (:mod:`.px4`): HEARTBEAT as MAV_AUTOPILOT_PX4 with PX4 custom modes (main mode << 16 |
  sub mode << 24), PX4-like default streams (ATTITUDE, ATTITUDE_QUATERNION, HIGHRES_IMU,
  GLOBAL/LOCAL_POSITION, GPS_RAW_INT, SYS_STATUS, EXTENDED_SYS_STATE, BATTERY_STATUS,
  HOME_POSITION), COMMAND_LONG/COMMAND_INT with COMMAND_ACK, OFFBOARD velocity setpoints with
  PX4's rules (SimVehicle: > 2 Hz before the switch, COM_OF_LOSS_T failsafe), a minimal
  parameter server and an empty mission.
- ``"ardupilot"`` (:mod:`.ardupilot`): HEARTBEAT as MAV_AUTOPILOT_ARDUPILOTMEGA with Copter mode
  numbers, nothing streamed but the heartbeat until asked (REQUEST_DATA_STREAM or
  SET_MESSAGE_INTERVAL), GUIDED velocity with a 3 s timeout, arming refused until the EKF/GPS
  delay has passed, RC_CHANNELS_OVERRIDE reflected in RC_CHANNELS (channel 5 is the flight-mode
  switch), MAVLink 2 signing.

The vehicle is built in layers, each module adding one job to the one below: :mod:`.link`
(socket, thread, parsing, sending, signing), :mod:`.params` (parameter server), :mod:`.rc_input`
(the pilot's radio and the companion's overrides), :mod:`.messages` (message builders and
streams), :mod:`.commands` (commands and setpoints), :mod:`.vehicle` (configuration and the
receive dispatch), then the two dialects.
"""
