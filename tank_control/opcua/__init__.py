"""OPC UA: the bridge to a server's variables (``bridge``), its parameters (``config``) and the
simulated plant served over OPC UA (``plant_server``). Pure Python on asyncua, no rclpy:
``nodes/opcua_bridge_node.py`` is the ROS adapter. docs/opcua.md."""
