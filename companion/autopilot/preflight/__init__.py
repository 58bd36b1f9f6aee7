"""Pre-flight check against the vehicle: is the autopilot configured the way the companion needs?

The rules are pure functions over what was read from the vehicle -- a dict of autopilot parameters
(name -> value, or :class:`~.report.ParamUnavailable` with the reason), a camera probe, a UWB
probe and a clock probe -- and the companion's own configuration (:class:`~.report.Requirements`),
so each rule is unit-testable with hand-written values: :mod:`.px4`, :mod:`.ardupilot` and
:mod:`.sensors`. :mod:`.readers` fetches those values from a connected backend and the sensors;
:mod:`.runner` runs every rule.

Every check ends in one :class:`~.report.CheckResult` row: ``ok``, ``wrong`` (with what to set)
or ``unknown`` (could not be read, with why). ``companion preflight`` prints the rows;
``companion fly`` refuses to start when any is ``wrong``.
"""
