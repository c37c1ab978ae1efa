"""The harness's recorder with its lockstep gate, spun in a thread of its own, for node tests.

A lockstep plant whose ``disturbance`` input is remapped to ``GATED_DISTURBANCE`` starts tick k+1
only once the recorder holds all of tick k, so a test records every tick however slowly its own
process runs. (A subscription of the test's probe would lose samples when the test process is
starved: the signal publishers keep only their last 10 messages.)"""
from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

from tank_control.harness.recorder import Recorder, Sink
from tank_control.harness.trace import GATED_DISTURBANCE

#: The plant's remapping that puts the recorder's gate on the serial path of each tick.
GATE_REMAP = ['-r', f'disturbance:={GATED_DISTURBANCE}']


@contextmanager
def gated_recorder(name: str, sink: Sink | None = None) -> Iterator[Recorder]:
    """A gated ``Recorder`` in rclpy's default context (``sink`` gets each message, from the
    recorder's thread), spun until the block ends, then destroyed."""
    from rclpy.utilities import get_default_context
    recorder = Recorder(get_default_context(), name=name, sink=sink)
    recorder.enable_gate()
    spinning = threading.Event()
    spinning.set()

    def spin() -> None:
        while spinning.is_set():
            recorder.spin_once(0.05)
    spinner = threading.Thread(target=spin, name=f'{name}_spin')
    spinner.start()
    try:
        yield recorder
    finally:
        spinning.clear()
        spinner.join()
        recorder.destroy()
