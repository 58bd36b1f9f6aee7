"""`companion campaign parity --autopilot <firmware>` for three seeds on the real firmware (PX4
v1.16 SIH, ArduCopter SITL): the embedded campaign with the firmware's profile (px4-sih,
arducopter-sitl) against the real firmware on the same draws (the short 12 m scenario), every
landing scored on the firmware's truth (PX4's HIL_STATE_QUATERNION, ArduCopter's SIM_STATE). On
ArduCopter one SITL flies the three landings (home reset to where each starts, SIM_WIND_* from the
draw)."""

from __future__ import annotations

import json
import math
import warnings

import pytest

from companion.config import shipped_params_path
from companion_lab.real_campaign import landing_diagnostics, run_parity

pytestmark = pytest.mark.firmware

LABEL = {"px4": "PX4 SIH", "ardupilot": "ArduCopter"}


def test_parity_on_three_seeds(firmware, tmp_path):
    name, _root = firmware
    # seed 7: draws no profile was traced or tuned on (the px4-sih profile's estimator states come
    # from seed 1)
    r = run_parity(name, 3, 7, shipped_params_path("landing_campaign_short.toml"), tmp_path)
    saved = json.loads((tmp_path / "parity.json").read_text())
    assert saved["comparison"]["fusion"]["seeds"] == [7000, 7001, 7002]
    assert (tmp_path / "parity.png").stat().st_size > 10_000
    real = r["real"]["landings"]["fusion"]
    pred = r["predicted"]["landings"]["fusion"]
    # the figures go into CI's output (a warning is printed even when the test passes): the real
    # landings depend on the machine (below), and this is how a CI run says why
    warnings.warn(
        f"{LABEL[name]} parity: real on {landing_diagnostics(real)}; "
        f"predicted {[round(x['error_m'], 3) for x in pred]}",
        stacklevel=1,
    )
    for x in real:
        assert x["delivered"] and x["failure"] == "", x
        assert x["markers_used"] > 20, x
        assert x["on_pad"], x
        if name == "px4":
            assert x["uwb_used"] > 20, x
            # a few cm on a free machine, up to ~25 cm on a loaded one (mostly control error); GPS
            # alone lands the displacement off (> 1 m, below)
            assert x["error_m"] < 0.4, x
    # the draws put the pad up to several metres from where GPS leads: fusion found it each time
    assert max(math.hypot(*x["pad_displacement_m"]) for x in real) > 1.0
    errs = [x["error_m"] for x in real]
    assert all(math.isfinite(e) for e in errs)
    if name == "ardupilot":
        # only ArduCopter's SITL flies the draws' wind (SIM_WIND_*; PX4 SIH has none, wind_m_s 0)
        assert any(x["wind_m_s"] > 1.0 for x in real)
        assert sum(errs) / len(errs) < 0.05  # the precision-landing target on ArduCopter: mean <= 5 cm
    c = r["comparison"]["fusion"]
    assert c["failure_classes_agree"]
    # three landings are too few for the 1.5x criterion (the command's 10+ are for that); their
    # mean ratio is held within 3x either way (0.66-1.5x on PX4 seeds 1-4)
    ratio = c["ratio_predicted_to_real"]["mean_m"]
    if name == "px4":
        assert 1 / 3 < ratio < 3, c
    else:
        # ArduCopter's landings are of a few millimetres each, which makes a ratio of noise: the
        # means within 1.5 cm pass too
        assert 1 / 3 < ratio < 3 or abs(c["predicted"]["mean_m"] - c["real"]["mean_m"]) < 0.015, c
