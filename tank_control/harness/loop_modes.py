"""controller_node's mode changes in a ROS run, from the recorded ``controller/loop_mode``
(nodes/loop_performance.py ``MODE_TOPIC``): the ``run.controller_modes`` log an in-process run
keeps (core/monitoring/modes.py), from which ``loop_performance`` computes a run's manual and
fail-safe times."""
from __future__ import annotations

import json
import math

from tank_control.harness.recording import RawMessage

TOPIC = 'controller/loop_mode'


class ModeChanges:
    """The ``[t, manual, fail_safe]`` changes, message by message; a malformed one is counted
    and left out."""

    def __init__(self) -> None:
        self.changes: list[list] = []
        self.unreadable = 0

    def add(self, raw: RawMessage) -> None:
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import String
        try:
            t, manual, fail_safe = json.loads(deserialize_message(raw.data, String).data)
            change = [float(t), bool(manual), bool(fail_safe)]
        except Exception:                          # noqa: BLE001 - a malformed message: counted
            self.unreadable += 1
            return
        if not math.isfinite(change[0]):
            self.unreadable += 1
            return
        self.changes.append(change)

    def result(self) -> list[list]:
        """The changes in time order."""
        return sorted(self.changes, key=lambda c: c[0])
