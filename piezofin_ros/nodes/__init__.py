"""ROS 2 adapters: thin rclpy nodes over the ROS-free core (one module per executable)."""
