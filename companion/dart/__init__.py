"""The Dart application (Dart paper): a cyber-pilot that holds a hover in front of a wall marker
and approaches it, flying the autopilot through RC overrides.

- :mod:`.mission`     the Dart mission (phases, parameters of a flight)
- :mod:`.control`     the PID position controllers
- :mod:`.mixer`       controller output -> RC channel values (the cyber-pilot's sticks)
- :mod:`.estimators`  the four estimators of the paper (FCF-CF, FCF-MF, SCF-MF-2DOF/3DOF)
- :mod:`.params`      the Dart parameter file (``params/dart_hover.toml``)
- :mod:`.shell`       the asyncio shell against a real autopilot
- :mod:`.bench`       microseconds per estimator step
"""
