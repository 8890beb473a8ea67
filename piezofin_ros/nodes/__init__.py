"""ROS 2 adapters: thin rclpy nodes over the ROS-free core, one module per executable.

``fin_sim`` streams the simulated rig (:mod:`..rig`) onto the topic contract, ``thrust_estimator``
runs :mod:`..estimation` on whatever publishes those topics (the simulator, a real rig driver, a
replayed bag), ``controller`` runs a strategy of :mod:`..control`, ``recorder`` and ``player`` write
and replay MCAP bags (:mod:`..bags`), and ``bringup`` hosts several of them in one process.  This is
the only package that imports rclpy; :mod:`._common` holds what the nodes share (parameters, QoS,
startup errors shown as one line).
"""
