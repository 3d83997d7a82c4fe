"""Skin simulator: presses on a patch → the CAN frames its modules would send. No ROS."""
