"""tactile_contact: contact shapes from capacitive robot skin.

The stages of the pipeline, each a sub-package (docs/architecture.md):

- :mod:`tactile_contact.canbus`: CAN bytes → module readings → ΔC per taxel (codec, period
  assembly, baseline tracking, bus health);
- :mod:`tactile_contact.model`: the physical model (module types, patch layouts, grids, the
  sensor's ΔC ↔ δ, elastic kernels, indenters, forward simulation);
- :mod:`tactile_contact.inverse`: one frame's reconstruction (detection → round-contact fit →
  grid fallback → summary) and its solvers;
- :mod:`tactile_contact.offline`: matrix bundles, their build, calibration from presses;
- :mod:`tactile_contact.sim`: the skin simulator (CAN frames of simulated presses);
- :mod:`tactile_contact.ros`: ROS 2 nodes, bringup, bags and the command line.

Everything but ``ros`` imports no ROS module. Old flat module paths
(``tactile_contact.codec``, ``tactile_contact.reconstruction``, ...) still import, with a
DeprecationWarning naming the new place (:mod:`tactile_contact._moved`).
"""

from __future__ import annotations

import pkgutil
from typing import TYPE_CHECKING, Any

from tactile_contact import _moved

# The generated message package (tactile_contact.msg) is installed by rosidl into site-packages
# while the Python sources may live in a source tree: let both directories form this package.
__path__ = pkgutil.extend_path(__path__, __name__)

__version__ = "0.1.0"

_moved.install()

if TYPE_CHECKING:
    from tactile_contact.inverse.reconstruction import ContactResult, Reconstructor
    from tactile_contact.inverse.summary import Contact

__all__ = ["Contact", "ContactResult", "Reconstructor", "__version__"]


def __getattr__(name: str) -> Any:
    # Lazy so that `import tactile_contact.canbus.codec` does not pull scipy in.
    if name in ("Reconstructor", "ContactResult"):
        from tactile_contact.inverse import reconstruction

        return getattr(reconstruction, name)
    if name == "Contact":
        from tactile_contact.inverse.summary import Contact

        return Contact
    raise AttributeError(f"module 'tactile_contact' has no attribute {name!r}")
