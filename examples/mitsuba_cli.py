#!/usr/bin/env python3
"""A stand-alone command-line renderer: Mitsuba 3 renders a scene file to an EXR.

It stands for "your own renderer" in gibench's worked example
(examples/README.md): gibench drives it through the ``command`` adapter as
an external executable and checks its images against gibench's stored
Mitsuba references.  It does not import gibench.

    python mitsuba_cli.py SCENE.xml OUT.exr [--variance VAR.exr] [--spp N]
        [--seed S] [--passes P] [--integrator path|direct] [--max-depth D]
        [--variant scalar_rgb|llvm_ad_rgb] [--counters FILE.json]
    python mitsuba_cli.py --version

What it changes in the scene, as gibench's references do: the integrator
is replaced by ``--integrator`` (``path`` with ``--max-depth``, or
``direct``), the film's reconstruction filter by ``box`` (Mitsuba's default
Gaussian would blur the image against a box-filtered reference) and the
sampler by ``independent``.  ``--spp`` samples are split over ``--passes``
independent renders (seeds ``seed * passes + k``); the image is their mean
and ``--variance`` their sample variance divided by the number of passes
(the variance of the mean, what gibench's Z-test needs).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path


def _scene_xml(path: Path, integrator: str, max_depth: int, spp: int) -> str:
    root = ET.parse(path).getroot()
    for old in root.findall("integrator"):
        root.remove(old)
    integ = ET.Element("integrator", {"type": integrator})
    if integrator == "path":
        ET.SubElement(integ, "integer", {"name": "max_depth", "value": str(max_depth)})
    root.insert(0, integ)
    for sensor in root.findall("sensor"):
        for s in sensor.findall("sampler"):
            sensor.remove(s)
        sampler = ET.SubElement(sensor, "sampler", {"type": "independent"})
        ET.SubElement(sampler, "integer", {"name": "sample_count", "value": str(spp)})
        for film in sensor.findall("film"):
            for f in film.findall("rfilter"):
                film.remove(f)
            ET.SubElement(film, "rfilter", {"type": "box"})
    return ET.tostring(root, encoding="unicode")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?")
    ap.add_argument("out", nargs="?")
    ap.add_argument("--variance")
    ap.add_argument("--counters")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--integrator", choices=("path", "direct"), default="path")
    ap.add_argument("--max-depth", type=int, default=-1)
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--version", action="store_true", help="print the Mitsuba version and exit")
    args = ap.parse_args(argv)

    import mitsuba as mi

    if args.version:
        print(f"mitsuba {mi.__version__} ({args.variant})")
        return 0
    if not args.scene or not args.out:
        ap.error("SCENE and OUT are required")
    if args.passes < 1 or args.spp < args.passes:
        ap.error("--spp must be >= --passes >= 1")
    import drjit as dr
    import numpy as np

    mi.set_variant(args.variant)
    scene_path = Path(args.scene).resolve()
    resolver = mi.file_resolver() if hasattr(mi, "file_resolver") else mi.Thread.thread().file_resolver()
    resolver.prepend(str(scene_path.parent))
    scene = mi.load_string(_scene_xml(scene_path, args.integrator, args.max_depth,
                                      args.spp // args.passes))
    t0 = time.perf_counter()
    images = []
    for k in range(args.passes):
        img = mi.render(scene, spp=args.spp // args.passes, seed=args.seed * args.passes + k)
        dr.eval(img)
        dr.sync_thread()                      # mi.render returns before the work is done
        images.append(np.array(img, dtype=np.float64)[..., :3])
    seconds = time.perf_counter() - t0
    stack = np.stack(images)
    mean = stack.mean(axis=0)
    mi.Bitmap(mean.astype(np.float32)).write(args.out)
    if args.variance:
        var = stack.var(axis=0, ddof=1) / args.passes if args.passes > 1 else np.zeros_like(mean)
        mi.Bitmap(var.astype(np.float32)).write(args.variance)
    if args.counters:
        h, w = mean.shape[:2]
        Path(args.counters).write_text(json.dumps({"camera_rays": w * h * (args.spp // args.passes)
                                                   * args.passes, "render_s": seconds}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
