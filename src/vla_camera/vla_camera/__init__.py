"""Publishes camera frames (webcam, video file or image folder) as sensor_msgs/Image with CameraInfo."""
