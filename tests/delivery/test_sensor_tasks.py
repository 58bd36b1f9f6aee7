"""A landing-sensor task that dies is reported when it dies, not when the shell ends."""

from __future__ import annotations

import asyncio
import logging

from companion.delivery.sensor_tasks import report_task_end


async def test_a_dead_sensor_task_is_logged_at_once_and_a_cancelled_one_is_not(caplog):
    async def crash() -> None:
        raise TypeError("detect() got an unexpected keyword argument 'down_cam'")

    async def forever() -> None:
        await asyncio.sleep(3600)

    with caplog.at_level(logging.ERROR, logger="companion.delivery.sensor_tasks"):
        task = asyncio.get_running_loop().create_task(crash())
        task.add_done_callback(report_task_end)
        await asyncio.sleep(0)  # the task runs and dies
        await asyncio.sleep(0)  # its done callback runs
        assert any("landing sensors stopped: TypeError" in r.getMessage() for r in caplog.records), caplog.text
        caplog.clear()
        quiet = asyncio.get_running_loop().create_task(forever())
        quiet.add_done_callback(report_task_end)
        await asyncio.sleep(0)
        quiet.cancel()
        await asyncio.sleep(0)
        await asyncio.sleep(0)
        assert not caplog.records
