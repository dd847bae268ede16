"""Write reduced copies of the third-party scenes, for a directory run that fits in minutes.

The scene files of ``suites/thirdparty`` render at up to 960x720 pixels; their
Mitsuba references (1024 spp x 8 passes) would take hours here.  This writes
each scene file, expanded to one self-contained file (:func:`core.xmlscene.expanded`:
includes spliced in, ``<path>`` folders absolute, ``$name`` substituted with
``-D spp=64`` for the files that expect it), with every film side divided by
``--divide`` (default 8: 960x720 becomes 120x90), into ``OUT``; then

    python examples/thirdparty_reduced.py OUT
    python -m gibench.cli run --scenes OUT --algorithm path --set spp=256

runs them as a directory run: each file is rendered and Z-tested against its
Mitsuba reference, or skipped with its one-line reason.  The own spp is 256:
at 64 the pixels some scenes light through rare paths have a sample mean and
variance too unreliable for the per-pixel test (Mitsuba's own ``path`` at 64
spp fails it on the spot scene, ``tests/test_spot.py``).  Files that do not load
are listed with the loader's reason and not written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lxml import etree

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from core.errors import GibenchError  # noqa: E402
from core.loader import load_scene  # noqa: E402
from core.xmlscene import expanded, resolve, substitute  # noqa: E402

THIRDPARTY = ROOT / "suites" / "thirdparty"


def scene_files() -> list[Path]:
    return sorted([*THIRDPARTY.glob("docs/scenes/*.xml"), *THIRDPARTY.glob("scenes/*/*.xml"),
                   *THIRDPARTY.glob("tests/scenes/*/*.xml")])


def reduced(path: Path, divide: int, defines: dict) -> str:
    """The expanded scene with ``$name`` substituted and film sides divided by ``divide``."""
    defaults = resolve(path, defines).defaults
    root = expanded(path, defines)
    for el in root.iter():
        if not isinstance(el.tag, str):
            continue
        for key, value in el.attrib.items():
            if "$" in value:
                el.set(key, substitute(value, defaults, lambda n: KeyError(n)))
    for el in list(root.iter("default")):
        el.getparent().remove(el)
    for film in root.iter("film"):
        for c in film:
            if isinstance(c.tag, str) and c.get("name") in ("width", "height"):
                c.set("value", str(max(1, round(int(float(c.get("value"))) / divide))))
    return etree.tostring(root, encoding="unicode")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--divide", type=int, default=8)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    written = 0
    for path in scene_files():
        defines = {"spp": "64"}
        try:
            load_scene(path, defines)
        except GibenchError as exc:
            print(f"not loaded: {exc}")
            continue
        name = f"{path.parent.name}__{path.name}"
        (args.out / name).write_text(reduced(path, args.divide, defines))
        load_scene(args.out / name)             # the copy loads as the original
        written += 1
    print(f"{written} of {len(scene_files())} scene files written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
