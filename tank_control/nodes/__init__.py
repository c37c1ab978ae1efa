"""Thin rclpy adapters around core objects: plant_node, controller_node, reference_node.

BLAS runs single-threaded in every node (set by the ``tank_control`` package on import).
"""
