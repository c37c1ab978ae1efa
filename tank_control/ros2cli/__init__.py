"""A small `ros2` command for environments without ros2cli (ROS 2 from PyPI wheels).

One module per verb: ``run``, ``param``, ``topic``, ``node``, ``service``. Output
and exit codes follow ros2cli where that is reasonable; when a real ros2cli is
importable, ``main`` hands over to it unchanged.
"""
