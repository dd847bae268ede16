"""The bottom package: what every layer of gibench shares.

The scene model (:mod:`core.scene`) and the one reader of Mitsuba 3 XML scene
files (:mod:`core.loader`, with :mod:`core.transforms` and :mod:`core.meshes`),
EXR and image I/O (:mod:`core.imageio`), the algorithm types
(:mod:`core.algorithm`), the case record (:mod:`core.records`), provenance
(:mod:`core.provenance`) and the one exception family (:mod:`core.errors`).
It imports no other package of the project; ``impl``, ``references`` and
``reports`` import it, and the application ``gibench`` sits on top.
"""
