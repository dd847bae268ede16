"""Own implementations of the thesis's algorithms, one module per concept.

Importing this package registers every algorithm with :mod:`gibench.registry`.
No module here knows about Mitsuba: they read the scene model and return
images and counters.
"""

from . import raycast  # noqa: F401  (registers 'raycast')
