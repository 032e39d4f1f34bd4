"""The COLMAP stages (pycolmap 4.x, CPU, one thread): workspace, SIFT, exhaustive matching,
known-pose triangulation or incremental SfM, and the sparse points with their observers."""
from __future__ import annotations

import contextlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ipm.errors import UserError
from ipm.io.views import Views
from ipm.render.cameras import gl_to_colmap


@dataclass
class Workspace:
    """A scratch directory with ``images/`` (links to the rgb files, named by view index) and
    ``database.db``."""

    root: Path
    names: list[str]
    """Image name of view i (``0000.png`` ...): COLMAP finds views by these names."""

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def database(self) -> Path:
        return self.root / "database.db"

    def index(self, name: str) -> int:
        """View index of a COLMAP image name."""
        return self.names.index(name)


def rgb_path(views: Views, i: int) -> Path:
    """The rgb file of view ``i``; ``UserError`` if it is missing."""
    frame = views.frames[i] if i < len(views.frames) else {}
    if "file_path" not in frame:
        raise UserError(f"frame {i} of {views.root / 'transforms.json'} has no file_path (rgb image)")
    path = views.root / frame["file_path"]
    if not path.is_file() and path.with_name(path.name + ".png").is_file():
        path = path.with_name(path.name + ".png")  # nerf-synthetic style paths without extension
    if not path.is_file():
        raise UserError(f"rgb image of frame {i} not found: {path}")
    return path


def make_workspace(views: Views, root: Path) -> Workspace:
    """Link (or copy) each view's rgb file into ``root/images`` as ``{index:04d}{suffix}``,
    after checking that it is an image of the size transforms.json gives."""
    from PIL import Image

    (root / "images").mkdir(parents=True, exist_ok=True)
    names = []
    for i in range(len(views)):
        src = rgb_path(views, i)
        try:
            with Image.open(src) as img:
                size = img.size
        except Exception as exc:
            raise UserError(f"cannot read rgb image {src}: {exc}") from None
        if size != (views.width, views.height):
            raise UserError(f"rgb image {src} is {size[0]}x{size[1]} px but transforms.json says "
                            f"{views.width}x{views.height}")
        name = f"{i:04d}{src.suffix.lower() or '.png'}"
        if views.lens is not None:  # a real lens: the image its pinhole twin sees, as the masks
            name = f"{i:04d}.png"
            with Image.open(src) as img:
                rgb = views.lens.resample(np.asarray(img.convert("RGB"))[None])[0]
            Image.fromarray(rgb).save(root / "images" / name)
        else:
            try:
                os.symlink(src.resolve(), root / "images" / name)
            except OSError:
                shutil.copyfile(src, root / "images" / name)
        names.append(name)
    return Workspace(root, names)


def intrinsics(views: Views) -> tuple[float, float, float]:
    """Pinhole focal length and principal point (f, cx, cy) in COLMAP pixels (centre at +0.5)."""
    f = 0.5 * views.width / np.tan(0.5 * views.fov_x)
    return float(f), 0.5 * views.width, 0.5 * views.height


@contextlib.contextmanager
def quiet_colmap(verbose: bool):
    """COLMAP's glog lines only when ``verbose`` (failures are reported in info.json)."""
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = old if verbose else 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def extract(ws: Workspace, views: Views, max_features: int, first_octave: int = -1) -> None:
    """SIFT on the CPU, one shared PINHOLE camera with the known intrinsics."""
    import pycolmap

    f, cx, cy = intrinsics(views)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = f"{f!r},{f!r},{cx!r},{cy!r}"
    opts = pycolmap.FeatureExtractionOptions()
    opts.num_threads = 1
    opts.use_gpu = False
    opts.sift.max_num_features = int(max_features)
    opts.sift.first_octave = int(first_octave)
    pycolmap.extract_features(ws.database, ws.images, image_names=ws.names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=opts, device=pycolmap.Device.cpu)


def match(ws: Workspace, seed: int) -> None:
    """Exhaustive SIFT matching and RANSAC two-view verification."""
    import pycolmap

    opts = pycolmap.FeatureMatchingOptions()
    opts.num_threads = 1
    opts.use_gpu = False
    verify = pycolmap.TwoViewGeometryOptions()
    verify.ransac.random_seed = int(seed)
    verify.ransac.num_threads = 1
    pycolmap.match_exhaustive(ws.database, matching_options=opts, verification_options=verify,
                              device=pycolmap.Device.cpu)


def pipeline_options(seed: int, two_view_tracks: bool):
    """Incremental-pipeline options: one thread, seeded, intrinsics fixed at the known ones."""
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = 1
    opts.random_seed = int(seed)
    opts.mapper.num_threads = 1
    opts.mapper.random_seed = int(seed)
    opts.triangulation.random_seed = int(seed)
    opts.triangulation.ignore_two_view_tracks = not two_view_tracks
    opts.extract_colors = False
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.mapper.abs_pose_refine_focal_length = False
    opts.mapper.abs_pose_refine_extra_params = False
    return opts


def known_pose_model(ws: Workspace, views: Views):
    """A ``Reconstruction`` holding the database's camera and images (ids and names from the
    database) registered at the known poses, without points."""
    import pycolmap

    db = pycolmap.Database.open(ws.database)
    try:
        cameras, images = db.read_all_cameras(), db.read_all_images()
    finally:
        db.close()
    rec = pycolmap.Reconstruction()
    for cam in cameras:
        rec.add_camera_with_trivial_rig(cam)
    for img in images:
        pose = pycolmap.Rigid3d(gl_to_colmap(views.c2w[ws.index(img.name)]))
        rec.add_image_with_trivial_frame(
            pycolmap.Image(name=img.name, camera_id=img.camera_id, image_id=img.image_id), pose)
    return rec


def triangulate_known(ws: Workspace, views: Views, seed: int):
    """Points triangulated (and merged, completed, filtered) at the known poses, two-view
    tracks kept; the poses stay fixed."""
    import pycolmap

    rec = known_pose_model(ws, views)
    out = ws.root / "sparse_known"
    out.mkdir(exist_ok=True)
    return pycolmap.triangulate_points(rec, ws.database, ws.images, out, clear_points=True,
                                       options=pipeline_options(seed, two_view_tracks=True),
                                       refine_intrinsics=False)


def incremental_sfm(ws: Workspace, seed: int, min_model_size: int = 3):
    """Incremental SfM without poses; the model with the most registered images, or None."""
    import pycolmap

    opts = pipeline_options(seed, two_view_tracks=True)
    opts.min_model_size = int(min_model_size)
    opts.multiple_models = False
    out = ws.root / "sparse_sfm"
    out.mkdir(exist_ok=True)
    models = pycolmap.incremental_mapping(ws.database, ws.images, out, options=opts)
    if not models:
        return None
    return max(models.values(), key=lambda r: r.num_reg_images())


def points_and_observers(rec, centres: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model's 3D points (n, 3), for each the mean unit direction towards the cameras that
    observe it (n, 3), and its track length (n,); ``centres`` maps image id to camera centre
    in the points' frame."""
    pts, dirs, lengths = [], [], []
    for p in rec.points3D.values():
        xyz = np.asarray(p.xyz, np.float64)
        d = np.zeros(3)
        for el in p.track.elements:
            c = centres.get(el.image_id)
            if c is not None:
                v = c - xyz
                d += v / max(np.linalg.norm(v), 1e-12)
        pts.append(xyz)
        dirs.append(d)
        lengths.append(p.track.length())
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int)
    return np.array(pts), np.array(dirs), np.array(lengths)
