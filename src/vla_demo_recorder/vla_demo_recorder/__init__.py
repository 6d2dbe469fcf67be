"""Records kinesthetic demonstrations to rosbag2 MCAP bags and turns bags into training pairs."""
