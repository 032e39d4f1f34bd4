"""Reading and writing the project's files: views (transforms.json), meshes, atomic outputs.

The names below are loaded from their modules on first use, so that a process writing a JSON file
(``ipm.io.atomic``) or reading views does not import the mesh libraries (trimesh, a second of
every job's start)."""
from ipm.io.lazy import lazy_names

_WHERE = {
    "atomic_dir": "atomic", "atomic_path": "atomic", "write_json": "atomic",
    "load_mesh": "mesh", "part_labels": "mesh", "save_glb": "mesh", "save_ply": "mesh",
    "shown_path": "paths",
    "Views": "views", "load_views": "views", "write_views": "views",
}

__all__ = sorted(_WHERE)
__getattr__, __dir__ = lazy_names(__name__, _WHERE)
