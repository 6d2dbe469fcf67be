"""What every package shares: robot constants and joint names, kinematics, the object and task
catalogue, the camera model, detections, image conversion, and ROS helpers.
"""
