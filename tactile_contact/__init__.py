"""tactile_contact: contact shapes from capacitive robot skin.

The core library (elastic kernels, sensor model, solvers, bundles, CAN codec) imports no ROS
module; the ROS 2 nodes live in :mod:`tactile_contact.nodes`.
"""

from __future__ import annotations

import pkgutil
from typing import TYPE_CHECKING, Any

# The generated message package (tactile_contact.msg) is installed by rosidl into site-packages
# while the Python sources may live in a source tree: let both directories form this package.
__path__ = pkgutil.extend_path(__path__, __name__)

__version__ = "0.1.0"

if TYPE_CHECKING:
    from tactile_contact.reconstruction import ContactResult, Reconstructor
    from tactile_contact.summary import Contact

__all__ = ["Contact", "ContactResult", "Reconstructor", "__version__"]


def __getattr__(name: str) -> Any:
    # Lazy so that `import tactile_contact.codec` does not pull scipy in.
    if name in ("Reconstructor", "ContactResult"):
        from tactile_contact import reconstruction

        return getattr(reconstruction, name)
    if name == "Contact":
        from tactile_contact.summary import Contact

        return Contact
    raise AttributeError(f"module 'tactile_contact' has no attribute {name!r}")
