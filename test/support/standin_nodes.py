"""Small lockstep stand-ins for plant_node and reference_node (harness tests only).

``plant``: an integrator y(k+1) = y(k) + ts·(u(k) + v) (exact ZOH), output ``y``,
input ``u``, no disturbance channel; it follows the lockstep protocol of
docs/nodes.md (tick k: /clock and measurement stamped t_k; advance once ``manipulated``
and ``disturbance`` stamped t_k are in; re-send every 0.5 s; ``lockstep.paused``
holds tick 0 until set to false, as plant_node does; ``lockstep.record_window``: tick k
only while k <= the tick the harness's recorder acknowledged on ``recorded`` + the window).
Parameter ``crash_at`` (s, 0 = never) makes it exit with code 3 at that simulated time;
``first_tick`` starts its clock at that tick instead of 0 (a plant already far
ahead, as another run's would be).
``reference``: setpoint ``y`` = ``step_value`` from ``step_time`` on (0 before),
an empty disturbance message, answering each /clock.

Run: ``python standin_nodes.py plant|reference --ros-args ...``.
"""
from __future__ import annotations

import sys

from builtin_interfaces.msg import Time
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (
    CLOCK_QOS,
    RECORDED_QOS,
    SIGNAL_QOS,
    TOPIC_RECORDED,
    clock_msg,
    stamp_to_ns,
    to_joint_state,
)
from tank_control.nodes.runtime import run_node


class StandinPlant(Node):
    def __init__(self) -> None:
        super().__init__('plant')
        self.ts_ns = int(round(self.declare_parameter('sample_time', 0.1).value * 1e9))
        self.crash_ns = int(round(self.declare_parameter('crash_at', 0.0).value * 1e9))
        self.declare_parameter('clock_mode', 'lockstep')
        self.declare_parameter('real_time_factor', 0.0)
        self.y = float(self.declare_parameter('initial_output', 0.0).value)
        self.k = int(self.declare_parameter('first_tick', 0).value)
        self.u: dict[int, float] = {}
        self.d: set[int] = set()
        self.clock_pub = self.create_publisher(Clock, '/clock', CLOCK_QOS)
        self.meas_pub = self.create_publisher(JointState, 'measurement', SIGNAL_QOS)
        self.create_subscription(JointState, 'manipulated', self.on_u, SIGNAL_QOS)
        self.create_subscription(JointState, 'disturbance', self.on_d, SIGNAL_QOS)
        self.paused = self.declare_parameter('lockstep.paused', False).value
        self.window = self.declare_parameter('lockstep.record_window', 0).value
        self.recorded = -1              # the recorder's last acknowledged tick
        self.held = False               # tick k waits for the recorder
        if self.window:
            self.create_subscription(Time, TOPIC_RECORDED, self.on_recorded, RECORDED_QOS)
        self.add_post_set_parameters_callback(self.on_set)
        self.create_timer(0.5, self.resend, clock=steady_clock())
        if not self.paused:
            self.publish_tick()

    def on_set(self, params) -> None:
        for p in params:
            if p.name == 'lockstep.paused':
                self.paused = p.value
                if not self.paused:
                    self.publish_tick()

    def resend(self) -> None:
        last = self.k - 1 if self.held else self.k
        if self.paused or (self.window and self.recorded < last - 1):
            return
        if self.held:          # tick k-1 again: the recorder may have missed its answers
            self.clock_pub.publish(clock_msg(last * self.ts_ns))
            self.meas_pub.publish(to_joint_state(last * self.ts_ns, ['y'], [self.last_y]))
        else:
            self.publish_tick()

    def allows(self, k: int) -> bool:
        """Tick 1 waits for the recorder to hold tick 0, later ones run ``window`` ahead."""
        return not self.window or k <= self.recorded + (self.window if self.recorded >= 0 else 1)

    def on_recorded(self, msg: Time) -> None:
        self.recorded = max(self.recorded, stamp_to_ns(msg) // self.ts_ns)
        if self.held and self.allows(self.k):
            self.held = False
            self.publish_tick()

    def publish_tick(self) -> None:
        t = self.k * self.ts_ns
        if self.crash_ns and t >= self.crash_ns:
            sys.stderr.write('standin plant: crashing on purpose\n')
            sys.stderr.flush()
            raise SystemExit(3)
        self.clock_pub.publish(clock_msg(t))
        self.meas_pub.publish(to_joint_state(t, ['y'], [self.y]))
        self.last_y = self.y

    def on_u(self, msg: JointState) -> None:
        self.u[stamp_to_ns(msg.header.stamp)] = msg.position[list(msg.name).index('u')]
        self.advance()

    def on_d(self, msg: JointState) -> None:
        self.d.add(stamp_to_ns(msg.header.stamp))
        self.advance()

    def advance(self) -> None:
        t = self.k * self.ts_ns
        if t in self.u and t in self.d:
            self.y = self.y + self.ts_ns * 1e-9 * self.u.pop(t)
            self.d.discard(t)
            self.k += 1
            if not self.allows(self.k):
                self.held = True
            else:
                self.publish_tick()


class StandinReference(Node):
    def __init__(self) -> None:
        super().__init__('reference')
        self.step_ns = int(round(self.declare_parameter('step_time', 1.0).value * 1e9))
        self.value = self.declare_parameter('step_value', 1.0).value
        self.declare_parameter('clock_mode', 'lockstep')
        self.sp_pub = self.create_publisher(JointState, 'setpoint', SIGNAL_QOS)
        self.d_pub = self.create_publisher(JointState, 'disturbance', SIGNAL_QOS)
        self.create_subscription(Clock, '/clock', self.on_clock, CLOCK_QOS)

    def on_clock(self, msg: Clock) -> None:
        t = stamp_to_ns(msg.clock)
        self.sp_pub.publish(to_joint_state(t, ['y'], [self.value if t >= self.step_ns else 0.0]))
        self.d_pub.publish(to_joint_state(t, [], []))


if __name__ == '__main__':
    kind = sys.argv.pop(1)
    rclpy_args = sys.argv
    sys.exit(run_node(StandinPlant if kind == 'plant' else StandinReference, rclpy_args))
