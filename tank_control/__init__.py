"""tank_control: process-control runtime for dead-time processes on ROS 2 Jazzy."""
