"""gyrocal import: tables, ROS 2 bags and MCAP files into the log contract."""
