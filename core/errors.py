"""The one exception family of gibench.

Every error that bad *input* can cause — a scene file, an image, a mesh, a
parameter value, a stored reference, a suite manifest, a baseline — is a
:class:`GibenchError`.  The command line prints it as one line,
``gibench: error: <message>``, and exits with status 2; any other exception is
a programming error and keeps its traceback.  Messages name the cause and,
where there is one, the place (``file:line``).

Each kind also derives from the built-in exception its callers would expect
(``ValueError`` for bad values, ``RuntimeError`` for a failed reference,
``NotImplementedError`` for a scene feature an algorithm does not model), so
library users can catch either.
"""

from __future__ import annotations

__all__ = ["GibenchError", "SceneError", "MeshError", "ImageError", "ParamError",
           "UnsupportedError", "ReferenceError_", "SuiteError", "StoreError", "UsageError"]


class GibenchError(Exception):
    """Bad input to gibench (never a programming error)."""


class SceneError(GibenchError, ValueError):
    """A scene file that is missing, malformed or outside the supported subset.

    The message is one line: ``file:line: <element type="...">: cause``.
    """


class MeshError(SceneError):
    """A mesh file (OBJ, PLY) that is missing or cannot be read."""


class ImageError(GibenchError, ValueError):
    """An image that cannot be used: missing, unreadable, wrong shape, non-finite."""


class ParamError(GibenchError, ValueError):
    """An unknown algorithm, an unknown parameter, or a value of the wrong type or range."""


class UnsupportedError(GibenchError, NotImplementedError):
    """A scene feature the chosen algorithm does not model (refused by name)."""


class ReferenceError_(GibenchError, RuntimeError):
    """A reference that cannot be had: Mitsuba cannot load or render the scene, or a
    stored entry is missing and rendering was not allowed.  (Trailing underscore:
    Python's built-in ``ReferenceError`` is about weak references.)"""


class SuiteError(GibenchError, ValueError):
    """A malformed suite manifest."""


class StoreError(GibenchError, RuntimeError):
    """A results file, history database or baseline that cannot be used."""


class UsageError(GibenchError, ValueError):
    """A bad command line: missing, conflicting or malformed options, a missing file."""
