"""Recording: the rosbag2 (MCAP) bag format and the recorder node that writes it."""
