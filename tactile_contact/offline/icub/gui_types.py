"""skinGui sensor types → this package's module types.

A skinGui ``[SENSORS]`` line names a drawing class of icub-main's iCubSkinGui plugin. Those
that are capacitive skin modules made of 12-channel CAN triangles map onto module types of
:mod:`tactile_contact.model.modules`; one GUI sensor may span several slots (the V2 palm: 48
channels = slots ``id .. id+3`` = CAN triangles ``id%16 .. id%16+3``). The other types are
known but cannot be modelled here, each for a stated reason; anything else is an unknown type.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class GuiType:
    """How one skinGui type is imported.

    Attributes:
        name: the skinGui type name.
        modules: this package's module type of each slot it occupies, in slot order.
        gui_units_per_mm: GUI drawing units per millimetre of the module template; None when
            the drawing is not the template up to scale (then the .ini alone cannot place it).
    """

    name: str
    modules: tuple[str, ...]
    gui_units_per_mm: float | None

    @property
    def slots(self) -> int:
        """Slots (12-channel CAN triangles) one sensor of this type occupies."""
        return len(self.modules)


SUPPORTED: dict[str, GuiType] = {
    t.name: t
    for t in (
        # Triangle_10pad.h draws the template in mils/40: 1 unit = 1.016 mm, origin taxel 3.
        GuiType("triangle_10pad", ("icub_v2_10pad",), 1.0 / 1.016),
        # Triangle.h (V1 ROBOSKIN, 12 taxels): the same channel order, origin the centroid, but
        # the drawing is not the physical module up to scale (only its 3-D rows place it).
        GuiType("triangle", ("roboskin12",), None),
        # PalmLeft.h / PalmRight.h: 48 channels, drawn at 1.2 units per template mm; the right
        # palm's template is the drawing mirror-imaged (see modules.py), so no .ini fallback.
        GuiType("palmL", tuple(f"icub_palm_left_{k}" for k in range(4)), None),
        GuiType("palmR", tuple(f"icub_palm_right_{k}" for k in range(4)), None),
    )
}

_FINGERTIP = (
    "a fingertip: 12 taxels on a cap about 7 mm in radius, curved in both directions "
    "(h/R ≈ 0.3), which no flattening keeps to the model's accuracy, and no positions file "
    "holds its 3-D taxels"
)

#: Known skinGui types that are left out, with the reason printed in the report.
UNSUPPORTED: dict[str, str] = {
    **{
        t: _FINGERTIP
        for t in (
            "fingertip",
            "fingertip2L",
            "fingertip2R",
            "fingertip3L",
            "fingertip3R",
            "fingertip4L",
            "fingertip4R",
            "fingertipMID",
        )
    },
    "quad16": "a POSFET test sensor, not a capacitive skin module",
    "fakePalm": "a display placeholder without taxels of its own",
    **{
        t: "a sensor of the R1 robot's hand, not an iCub skin module"
        for t in ("cer_sh_pdl", "cer_sh_pdr", "cer_sh_pp", "cer_sh_td", "cer_sh_tp")
    },
}


def known_types() -> list[str]:
    """Every skinGui type name this importer recognises (supported or not)."""
    return sorted([*SUPPORTED, *UNSUPPORTED])
