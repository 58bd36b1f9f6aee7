"""`companion campaign parity --autopilot px4` for three seeds on the real PX4 v1.16 SIH: the
embedded campaign with the px4-sih profile against the real firmware on the same draws (the short
12 m scenario), every landing scored on PX4's HIL_STATE_QUATERNION truth."""

from __future__ import annotations

import json
import math
import warnings

import pytest

from companion.config import shipped_params_path
from companion_lab.real_campaign import landing_diagnostics, run_parity

pytestmark = pytest.mark.firmware


def test_parity_on_three_seeds(px4_root, tmp_path):
    # seed 7: draws no profile was traced on (the px4-sih profile's estimator states come from seed 1)
    r = run_parity("px4", 3, 7, shipped_params_path("landing_campaign_short.toml"), tmp_path)
    saved = json.loads((tmp_path / "parity.json").read_text())
    assert saved["comparison"]["fusion"]["seeds"] == [7000, 7001, 7002]
    assert (tmp_path / "parity.png").stat().st_size > 10_000
    real = r["real"]["landings"]["fusion"]
    pred = r["predicted"]["landings"]["fusion"]
    # the figures go into CI's output (a warning is printed even when the test passes): the real
    # landings depend on the machine (below), and this is how a CI run says why
    warnings.warn(
        f"PX4 SIH parity: real on {landing_diagnostics(real)}; predicted {[round(x['error_m'], 3) for x in pred]}",
        stacklevel=1,
    )
    for x in real:
        assert x["delivered"] and x["failure"] == "", x
        assert x["markers_used"] > 20 and x["uwb_used"] > 20, x
        # a few cm on a free machine, up to ~25 cm on a loaded one (mostly control error); GPS
        # alone lands the displacement off (> 1 m, below)
        assert x["on_pad"] and x["error_m"] < 0.4, x
    # the draws put the pad up to several metres from where GPS leads: fusion found it each time
    assert max(math.hypot(*x["pad_displacement_m"]) for x in real) > 1.0
    c = r["comparison"]["fusion"]
    assert c["failure_classes_agree"]
    # three landings are too few for the 1.5x criterion (the command's 10+ are for that); their
    # mean ratio is held within 3x either way (0.66-1.5x on seeds 1-4)
    assert 1 / 3 < c["ratio_predicted_to_real"]["mean_m"] < 3, c
