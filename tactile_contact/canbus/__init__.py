"""CAN side: bytes → module readings → ΔC per taxel. No ROS import.

- :mod:`.codec`: ROBOSKIN / iCub skin frames ↔ 8-bit channel values (pure bytes ↔ arrays);
- :mod:`.assembler`: the two frames of a triangle's period → one complete reading;
- :mod:`.baseline`: per-taxel baseline tracking (frozen during contact), 8-bit values → ΔC [F];
- :mod:`.stream`: a python-can bus → per-patch frames of readings (gathering, drops, stamps);
- :mod:`.bus_health`: bus state and error counters for diagnostics;
- :mod:`.fuzz`: malformed-frame generators for the driver's robustness tests.
"""
