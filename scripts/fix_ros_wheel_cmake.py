"""Point the ROS 2 wheels' exported CMake files at this interpreter's include directories.

The PyPI wheels of ROS 2 are built in a manylinux image and their exported targets name that
image's Python and numpy include directories, which do not exist here; rosidl's Python type
support then fails to configure. Rewrites those paths in place (idempotent) under
``<venv>/share``. Run with the venv's interpreter.
"""

from __future__ import annotations

import re
import sys
import sysconfig
from pathlib import Path

import numpy as np

MANYLINUX_PYTHON = re.compile(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+")
MANYLINUX_NUMPY = re.compile(
    r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/_core/include"
)


def main() -> int:
    share = Path(sys.prefix) / "share"
    py_include = sysconfig.get_paths()["include"]
    np_include = np.get_include()
    changed = 0
    for path in share.glob("*/cmake/*.cmake"):
        text = path.read_text()
        if "/opt/python/" not in text:
            continue
        new = MANYLINUX_NUMPY.sub(np_include, text)
        new = MANYLINUX_PYTHON.sub(py_include, new)
        if new != text:
            path.write_text(new)
            changed += 1
    print(
        f"fix_ros_wheel_cmake: {changed} file(s) rewritten "
        f"(python {py_include}, numpy {np_include})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
