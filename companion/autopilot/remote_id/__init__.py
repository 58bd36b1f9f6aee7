"""Remote ID (OpenDroneID) for the autopilot's transponder, docs/remote-id.md: the messages built
from ``[remote_id]`` (:mod:`.messages`), when they are due (:mod:`.schedule`), and the
transponder's ARM_STATUS with the arming gate on it (:mod:`.arm_status`)."""
