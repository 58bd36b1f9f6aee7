"""The GPS cut of the real-firmware GNSS-lost flights and campaign variants (lab/gnss_cut.py): when
it cuts (on a scripted truth), which call cuts on each firmware, the parameters each boots with."""

from __future__ import annotations

import asyncio

import pytest

from companion_lab.gnss_cut import GPS_ENABLE_PARAM, GPS_STOP, cut_gps_when_low, gnss_loss_boot_params, sitl_gps_cut


class DescendingTruth:
    """A truth feed (MavlinkTruth's pn, pe, pd, age_s) that climbs to 12 m, moves over the pad and
    comes down at 5 m/s, on the loop's clock; it records the link calls a cut makes."""

    def __init__(self) -> None:
        self.t0 = asyncio.get_running_loop().time()
        self.calls: list[tuple[str, ...]] = []
        self.age_s = 0.0

    def _t(self) -> float:
        return asyncio.get_running_loop().time() - self.t0

    @property
    def pd(self) -> float:  # up to -12 m by 0.3 s, then down at 5 m/s
        t = self._t()
        return -min(12.0, 40.0 * t) if t < 0.3 else -max(0.0, 12.0 - 5.0 * (t - 0.3))

    @property
    def pn(self) -> float:
        return 20.0 if self._t() < 0.2 else 0.3  # away from the pad, then over it

    pe = 0.0

    def set_param(self, name: str, value: float) -> None:
        self.calls.append(("set_param", name, str(value)))

    def shell(self, line: str) -> None:
        self.calls.append(("shell", line))


async def test_the_cut_comes_once_coming_down_through_the_height_near_the_pad():
    truth = DescendingTruth()
    out: dict[str, float] = {}
    loop = asyncio.get_running_loop()
    ground = 0.0
    await asyncio.wait_for(
        cut_gps_when_low(truth, (0.0, 0.0), 3.0, 6.0, out, loop.time, sitl_gps_cut("ardupilot", truth)), 5.0
    )
    assert truth.calls == [("set_param", GPS_ENABLE_PARAM, "0.0")]
    assert 2.0 <= out["height_m"] <= 3.0 and out["height_m"] > ground  # on the way down, just below 3 m
    # the cut's time is when that height was read: 5 m/s down from 12 m since 0.3 s
    assert out["time_s"] - truth.t0 == pytest.approx(0.3 + (12.0 - out["height_m"]) / 5.0, abs=0.05)


async def test_px4_stops_its_simulated_receiver_in_the_shell():
    truth = DescendingTruth()
    sitl_gps_cut("px4", truth)()
    assert truth.calls == [("shell", GPS_STOP)] and GPS_STOP == "sensor_gps_sim stop"
    with pytest.raises(ValueError, match=r"autopilot 'sim': the GPS cut is built for 'ardupilot' and 'px4'"):
        sitl_gps_cut("sim", truth)


def test_gnss_loss_boot_params_are_each_firmwares_external_nav_parameters():
    assert gnss_loss_boot_params("px4") == {"EKF2_EV_CTRL": 1.0}
    ap = gnss_loss_boot_params("ardupilot")
    assert ap["VISO_TYPE"] == 1.0 and ap["EK3_SRC2_POSXY"] == 6.0 and ap["FS_EKF_ACTION"] == 1.0
    with pytest.raises(ValueError, match=r"autopilot 'sim': expected one of"):
        gnss_loss_boot_params("sim")
