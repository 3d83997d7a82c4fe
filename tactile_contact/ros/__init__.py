"""ROS 2 side: nodes (thin adapters over the core library), bringup, bags, command line."""
