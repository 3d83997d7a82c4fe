"""One frame's reconstruction: taxel compressions → contacts, pressure, deflection. No ROS.

:class:`tactile_contact.inverse.reconstruction.Reconstructor` chains the stages (see
docs/architecture.md); the solvers of the grid path are in :mod:`.solvers`.
"""
