"""Topic names of the pipeline, in one place for nodes, bags, tests and the demo.

All names are relative (resolved in the node's namespace) and prefixed by the patch name.
"""

from __future__ import annotations

from sensor_msgs.msg import Image

from tactile_contact.model.layout import load_layout
from tactile_contact.msg import ContactState, TaxelArray

#: suffix → message class of the per-patch streams worth recording.
STREAMS: dict[str, type] = {
    "taxels": TaxelArray,
    "contact": ContactState,
    "contact_truth": ContactState,
    "traction": Image,
    "deflection": Image,
}


def patch_topic(patch: str, suffix: str) -> str:
    """``<patch>/<suffix>``, e.g. ``hexagon/contact``."""
    return f"{patch}/{suffix}"


def pipeline_topics(
    layout_path: str, suffixes: tuple[str, ...] = tuple(STREAMS)
) -> dict[str, type]:
    """Absolute topic → message class for every patch of a layout (no namespace)."""
    layout = load_layout(layout_path)
    return {"/" + patch_topic(p.name, s): STREAMS[s] for p in layout.patches for s in suffixes}
