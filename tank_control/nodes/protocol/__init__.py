"""The clock protocols of the nodes as pure objects (no rclpy): one per clock mode and role.

Each takes stamped inputs (and timer calls) and returns what to publish, stamped; the node
classes only wire subscriptions, timers and publishers to them (docs/nodes.md, "Clock modes").
Times in integer nanoseconds.
"""
