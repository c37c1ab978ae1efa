"""A controller's state changes in a ROS run, from the recorded ``/parameter_events``.

A kind with a state machine (the relay auto-tuner's ``autotune.state``) writes each new state and
``<machine>.state_time`` (the loop time [s] of the first sample in that state) to read-only
parameters; their change events are recorded in run.mcap like every other topic. This turns them
into the ``run.controller_states`` list an in-process run keeps — ``[(t, state), ...]`` in the
order the states were entered — so plot.png marks the states of a ROS run too. A state entered by
a command is written before its first sample, and its ``state_time`` follows in a later event;
the later event moves the mark."""
from __future__ import annotations

from tank_control.harness.recording import RawMessage

TYPE = 'rcl_interfaces/msg/ParameterEvent'


class StateChanges:
    """The state changes of node ``node`` (its name without namespace), event by event."""

    def __init__(self, node: str = 'controller') -> None:
        self.node = node
        self.changes: list[list] = []              # [t or None, machine, state]
        self.unreadable = 0

    def add(self, raw: RawMessage) -> None:
        from rcl_interfaces.msg import ParameterEvent
        from rclpy.serialization import deserialize_message
        try:
            event = deserialize_message(raw.data, ParameterEvent)
        except Exception:                          # noqa: BLE001 - a malformed message: counted
            self.unreadable += 1
            return
        if event.node.rsplit('/', 1)[-1] != self.node:
            return
        values = {p.name: p.value for p in event.changed_parameters}
        for name, value in values.items():
            machine, _, field = name.rpartition('.')
            if field == 'state' and machine:
                timed = values.get(f'{machine}.state_time')
                t = float(timed.double_value) if timed is not None else None
                self.changes.append([t, machine, str(value.string_value)])
            elif field == 'state_time' and f'{machine}.state' not in values:
                last = next((c for c in reversed(self.changes) if c[1] == machine), None)
                if last is not None:
                    last[0] = float(value.double_value)

    def result(self) -> list[tuple[float, str]]:
        """``[(t, state), ...]``; a state whose time never came is left out."""
        return [(t, state) for t, _, state in self.changes if t is not None]
