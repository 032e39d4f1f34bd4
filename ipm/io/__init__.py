"""Reading and writing the project's files: views (transforms.json), meshes, atomic outputs."""
from ipm.io.atomic import atomic_dir, atomic_path, write_json
from ipm.io.mesh import load_mesh, part_labels, save_glb, save_ply
from ipm.io.paths import shown_path
from ipm.io.views import Views, load_views, write_views

__all__ = [
    "Views", "atomic_dir", "atomic_path", "load_mesh", "load_views", "part_labels", "save_glb", "save_ply",
    "shown_path", "write_json", "write_views",
]
