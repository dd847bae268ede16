"""Small suite manifests written by tests (one raycast group over given scenes)."""

from pathlib import Path

from core.provenance import REPO_ROOT


def raycast_suite(path: Path, name: str, scenes, *, spp: int, light_samples: int,
                  expect: str = "report", label: str = "raycast",
                  **suite_keys) -> Path:
    """Write a suite manifest to ``path``: one ``raycast`` group (direct transport) over
    ``scenes`` (paths relative to ``suites/`` or absolute), one configuration with
    ``spp`` and ``light_samples`` under ``label`` (keep it when comparing two
    manifests as the same case); ``suite_keys`` go into ``[suite]`` (e.g.
    ``reference_spp=8``).  Returns ``path``."""
    listed = ", ".join(f'"{Path(REPO_ROOT / "suites" / s).as_posix()}"' for s in scenes)
    keys = "".join(f"{k} = {v!r}\n" for k, v in suite_keys.items())
    path.write_text(f"""
[suite]
name = "{name}"
repeats = 1
{keys}[[group]]
scenes = [{listed}]
algorithm = "raycast"
transport = "direct"
[[group.config]]
label = "{label}"
params = {{ spp = {spp}, light_samples = {light_samples} }}
expect = "{expect}"
""")
    return path
