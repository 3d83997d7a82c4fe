"""Offline tools: matrix bundles (:mod:`.bundle`), their build from a layout (:mod:`.build`),
presses of known force and place (:mod:`.presses`) and the calibration of a patch's taxel
response from them (:mod:`.calibrate`). No ROS import."""
