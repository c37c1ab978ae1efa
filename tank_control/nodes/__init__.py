"""Thin rclpy adapters around core objects."""
