"""Importing a real iCub skin part (skinGui .ini, positions .txt, robot skin spec) as a layout.

One module per concern: :mod:`.ini`, :mod:`.positions` and :mod:`.robot_xml` read the files,
:mod:`.gui_types` maps skinGui sensor types to module types, :mod:`.slots` matches slots, CAN
addresses and rows (and records the files' anomalies), :mod:`.surface_fit` fits and unrolls the
surface, :mod:`.placement` places the modules and measures the flattening, :mod:`.importer`
chooses the patches and writes the YAML, :mod:`.report` holds what is printed, :mod:`.cli` is
``tactile-contact-import-icub``. Pure core: no ROS. docs/icub.md is the user's guide.
"""

from tactile_contact.offline.icub.errors import IcubFileError
from tactile_contact.offline.icub.importer import ImportResult, import_part

__all__ = ["IcubFileError", "ImportResult", "import_part"]
