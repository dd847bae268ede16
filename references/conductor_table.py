"""Write ``impl/data/conductors_rgb.json``: the RGB complex indices of refraction
Mitsuba 3's RGB variants give its named conductors (``material="Au"`` etc.).

Mitsuba reads each name's measured spectra (``data/ior/<name>.eta.spd`` and
``.k.spd`` of its distribution) and, in an RGB variant, turns each into one
linear sRGB triple when the ``conductor`` / ``roughconductor`` plugin is built.
This script asks the installed Mitsuba for those triples (``mi.traverse`` of a
``conductor`` with each name) and stores them with the Mitsuba version and
variant, so the own tracers reproduce what Mitsuba's RGB render uses without
importing Mitsuba.  ``tests/test_named_conductors.py`` checks the stored table
against the installed Mitsuba.

Run: ``python -m references.conductor_table`` (rewrites the file).
"""

from __future__ import annotations

import json
from pathlib import Path

from .mitsuba_env import load_mitsuba

TABLE = Path(__file__).resolve().parent.parent / "impl" / "data" / "conductors_rgb.json"


def conductor_names(mi) -> list[str]:
    """The names Mitsuba's conductors accept: the spectra with both an ``eta`` and a ``k`` file."""
    root = Path(mi.__file__).resolve().parent / "data" / "ior"
    eta = {p.name[: -len(".eta.spd")] for p in root.glob("*.eta.spd")}
    k = {p.name[: -len(".k.spd")] for p in root.glob("*.k.spd")}
    return sorted(eta & k)


def mitsuba_rgb_ior(mi, name: str) -> tuple[list[float], list[float]]:
    """(eta, k) as linear sRGB triples of Mitsuba's ``conductor`` with ``material=name``."""
    params = mi.traverse(mi.load_dict({"type": "conductor", "material": name}))
    import numpy as np

    eta = np.asarray(params["eta.value"], dtype=np.float64).reshape(-1)
    k = np.asarray(params["k.value"], dtype=np.float64).reshape(-1)
    if eta.shape != (3,) or k.shape != (3,):
        raise ValueError(f"{name}: expected RGB eta and k from Mitsuba, got {eta.shape}, {k.shape}")
    # float32 values, written with the 9 digits that restore them exactly
    return [float(f"{x:.9g}") for x in eta], [float(f"{x:.9g}") for x in k]


def build() -> dict:
    mi = load_mitsuba()
    return {
        "source": "Mitsuba 3's named conductor spectra (data/ior/<name>.eta.spd, .k.spd) as its RGB "
                  "variant converts them; written by references/conductor_table.py",
        "mitsuba": mi.__version__,
        "variant": mi.variant(),
        "materials": {name: dict(zip(("eta", "k"), mitsuba_rgb_ior(mi, name)))
                      for name in conductor_names(mi)},
    }


if __name__ == "__main__":
    table = build()
    TABLE.parent.mkdir(parents=True, exist_ok=True)
    rows = ",\n".join(f"  {json.dumps(name)}: {json.dumps(v)}" for name, v in table["materials"].items())
    head = json.dumps({k: v for k, v in table.items() if k != "materials"}, indent=1)[:-2]
    TABLE.write_text(f'{head},\n "materials": {{\n{rows}\n }}\n}}\n')
    print(f"{TABLE}: {len(table['materials'])} conductors (Mitsuba {table['mitsuba']}, {table['variant']})")
