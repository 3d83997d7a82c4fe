"""ROS 2 nodes of tactile_contact: thin adapters over the core library (no logic of their own)."""
