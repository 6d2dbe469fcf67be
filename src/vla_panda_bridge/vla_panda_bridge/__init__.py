"""The robot side: a MuJoCo-backed simulated Panda and a ros2_control forwarder, behind one safety layer."""
