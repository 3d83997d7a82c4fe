"""Offline tools: matrix bundles (:mod:`.bundle`), their build from a layout (:mod:`.build`),
and calibration of a patch's taxel response from presses of known force and place
(:mod:`.calibrate`). No ROS import."""
