"""Pure numpy/scipy core: plants, controllers, tuning, analysis. Never imports rclpy."""
