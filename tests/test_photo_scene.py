"""Photograph-like references (``ipm.render.photo_scene``, the ``photo`` layout of synth), the
learned segmenter (``ipm.learned.segmenter``, ``ipm.segment.mask_from_photo``) and the photo rows."""
from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from ipm.errors import UserError


def _box(lo=(-0.3, 0.0, -0.3), hi=(0.3, 0.8, 0.3)):
    import trimesh

    box = trimesh.creation.box(bounds=np.array([lo, hi]))
    return np.asarray(box.vertices), np.asarray(box.faces), np.zeros((len(box.faces), 3, 2))


@pytest.fixture(scope="module")
def photo_case(tmp_path_factory, mitsuba_cpu):
    """cup_1 in the photo layout at 96 px: one photograph-like view and its true mask."""
    from ipm.synth import synthesize

    out = tmp_path_factory.mktemp("photo") / "cup_1"
    synthesize("cup_1", out, n_views=1, res=96, spp=8, progress=False, layout="photo")
    return out


@pytest.mark.parametrize("backdrop", ["gradient", "table", "floor"])
def test_the_object_casts_its_shadow_on_the_ground(mitsuba_cpu, backdrop):
    """The ground beside the box on the far side from the sun is darker, against the ground on the
    sun's side, than in the same scene without the box; the image is finite in [0, 1]."""
    from ipm.render.cameras import orbit_camera
    from ipm.render.photo_scene import render_photo, sun_direction

    v, f, uv = _box()
    c2w = orbit_camera(np.array([0.0, 0.4, 0.0]), 3.0, 20.0, 25.0)[None]
    with_box = render_photo(v, f, uv, c2w, 0.7, 48, 48, backdrop, seed=3, plain=(0.8, 0.1, 0.1), spp=16)[0]
    assert with_box.shape == (48, 48, 3) and np.isfinite(with_box).all()
    assert with_box.min() >= 0 and with_box.max() <= 1
    light = sun_direction(np.random.default_rng(3))
    away = np.array([light[0], 0.0, light[2]]) / np.hypot(light[0], light[2])
    from ipm.render.cameras import project

    # ground points outside the box: on the far side from the sun (shadowed) and on its side (lit)
    (sx, sy), (lx, ly) = project(np.stack([0.55 * away, -0.55 * away]), c2w[0], 0.7, 48, 48).astype(int)
    tiny = _box((-0.01, 0.0, -0.01), (0.01, 0.02, 0.01))  # the same scene's ground, the box almost gone
    bare = render_photo(*tiny, c2w, 0.7, 48, 48, backdrop, seed=3, plain=(0.8, 0.1, 0.1), spp=16)[0]

    def ratio(img):  # shadowed over lit ground: exposure and the ground's pattern cancel against ``bare``
        return img[sy - 1:sy + 2, sx - 1:sx + 2].mean() / img[ly - 1:ly + 2, lx - 1:lx + 2].mean()

    shade = ratio(with_box) / ratio(bare)
    assert shade < 0.75, (backdrop, shade)


def test_each_part_wears_its_own_texture(mitsuba_cpu):
    """A photographed box whose lower and upper halves are two parts, one red and one blue: the
    pixels of each half show its part's colour (the photo layout dresses a case as its reference
    views are dressed, a texture per part); textures per part without labels are refused."""
    from ipm.render.cameras import orbit_camera, project
    from ipm.render.photo_scene import render_photo

    v, f, uv = _box()
    labels = (v[f].mean(1)[:, 1] > 0.4).astype(int)  # the top face and the sides' upper triangles
    red, blue = np.full((4, 4, 3), (0.8, 0.05, 0.05)), np.full((4, 4, 3), (0.05, 0.05, 0.8))
    c2w = orbit_camera(np.array([0.0, 0.4, 0.0]), 3.0, 20.0, 25.0)[None]
    img = render_photo(v, f, uv, c2w, 0.7, 48, 48, "gradient", seed=3, texture={0: red, 1: blue}, spp=16,
                       labels=labels)[0]
    centres = v[f].mean(1)
    for part, channel in ((0, 0), (1, 2)):
        x, y = project(centres[labels == part], c2w[0], 0.7, 48, 48).mean(0).astype(int)
        pixel = img[y, x]
        assert pixel[channel] > 2 * pixel[2 - channel], (part, pixel)
    with pytest.raises(ValueError, match="labels"):
        render_photo(v, f, uv, c2w, 0.7, 16, 16, "gradient", texture={0: red}, spp=4)


def test_unknown_backdrops_are_refused():
    from ipm.render.photo_scene import ground_texture

    with pytest.raises(ValueError, match="unknown backdrop 'moon'"):
        ground_texture("moon", np.random.default_rng(0))


def test_the_photo_layout_writes_jpegs_and_true_masks(photo_case):
    """JPEG photographs (the ground fills the frame: no pixel is the flat background of the other
    layouts), true masks beside them, and the case's photo setting fixed by its name."""
    from ipm.synth import photo_setting

    meta = json.loads((photo_case / "transforms.json").read_text())
    frame = meta["frames"][0]
    assert frame["file_path"].endswith(".jpg")
    with Image.open(photo_case / frame["file_path"]) as img:
        assert img.format == "JPEG" and img.size == (96, 96)
        rgb = np.asarray(img.convert("RGB")).astype(float)
    mask = np.asarray(Image.open(photo_case / frame["mask_path"])) > 127
    assert 0.05 < mask.mean() < 0.8
    assert rgb[~mask].std() > 3  # a lit, textured ground and sky, not one flat colour
    assert photo_setting("cup_1") == photo_setting("cup_1") and photo_setting("cup_1")["backdrop"]


def test_a_distorted_photo_case_writes_its_lens_and_reads_back_as_its_pinhole_twin(photo_case, mitsuba_cpu):
    """cup_1 is photographed through a barrel lens: transforms.json gives its k1 (the lens read back),
    and its masks read back match the pinhole render of the true mesh. (Where the lens draws what,
    in pixels: ``tests/test_lens.py``; at 96 px the object's edge moves by under half a pixel.)"""
    from ipm.io.views import load_views
    from ipm.metrics.silhouette import view_ious
    from ipm.render.silhouette import SilhouetteRenderer
    from ipm.cases import load_case
    from ipm.synth import PHOTO_DISTORTION, ground_truth_mesh, photo_setting

    share = photo_setting("cup_1")["distortion"]
    assert PHOTO_DISTORTION[0] <= share <= PHOTO_DISTORTION[1]
    meta = json.loads((photo_case / "transforms.json").read_text())
    corner = np.hypot(48.0, 48.0) / meta["fl_x"]  # the corner's distance from the centre, normalised
    assert meta["camera_model"] == "OPENCV" and meta["k1"] == pytest.approx(-share / corner**2)
    views = load_views(photo_case / "transforms.json")
    assert views.lens is not None
    v, f, _, _ = ground_truth_mesh(load_case("cup_1"))
    pinhole = SilhouetteRenderer(views.c2w, views.fov_x, 96, 96, spp=16).render(v, f) > 0.5
    assert view_ious(pinhole, views.masks > 0.5)[0] > 0.97


def test_the_photo_layout_refuses_trees(tmp_path, mitsuba_cpu):
    from ipm.synth import synthesize

    with pytest.raises(UserError, match="photo layout renders cups and buildings"):
        synthesize("tree_1", tmp_path / "t", res=32, spp=2, progress=False, layout="photo")


@pytest.mark.slow
def test_training_photos_show_the_object_where_its_mask_is(mitsuba_cpu, tmp_path):
    """Three training photos (a cup and two buildings on random grounds): JPEG files of the
    network's size, masks that cover part of the frame, the object's pixels unlike the ground's;
    ranges rendered apart and stored join into the same photos."""
    from ipm.learned.segmenter import SEG_RES
    from ipm.learned.segmenter_training import decoded, load_photos, make_photos, save_photos

    data = make_photos(3, seed=5, spp=4)
    images = decoded(data)
    assert images.shape == (3, SEG_RES, SEG_RES, 3) and images.dtype == np.uint8
    assert data["mask"].shape == (3, SEG_RES, SEG_RES)
    for image, mask in zip(images.astype(float), data["mask"]):
        assert 0.02 < mask.mean() < 0.8
        assert np.abs(image[mask].mean(0) - image[~mask].mean(0)).max() > 2
    later = make_photos(2, seed=5, spp=4, start=1)  # a range made apart is the same photos
    assert np.array_equal(later["mask"], data["mask"][1:]) and later["jpeg"] == data["jpeg"][1:]
    save_photos(tmp_path / "a.npz", make_photos(1, seed=5, spp=4))
    save_photos(tmp_path / "b.npz", later)
    joined = load_photos(tmp_path / "a.npz", tmp_path / "b.npz")
    assert joined["jpeg"] == data["jpeg"] and np.array_equal(joined["mask"], data["mask"])
    assert joined["ranges"] == [[0, 1], [1, 3]]  # which photos of the sequence a training saw
    (tmp_path / "bad.npz").write_text("not photos")
    with pytest.raises(UserError, match="unreadable training photos"):
        load_photos(tmp_path / "bad.npz")


def test_stemmed_vessels_stand_on_a_foot_below_a_bowl():
    """The segmenter's photos of vessels on a stem: dishes parameters in the generator's bounds, no
    handle, a profile whose stem is narrower than half its foot and half its rim; a seeded draw."""
    from ipm.generators import get_generator
    from ipm.learned.segmenter_training import stemmed_vessel

    gen = get_generator("dishes")
    for seed in range(20):
        x = stemmed_vessel(gen, np.random.default_rng(seed))
        assert np.array_equal(x, gen.spec.clip(x)) and x[gen.spec.index["has_handle"]] == 0
        stem = x[1:3].max()
        assert stem < 0.5 * x[0] and stem < 0.5 * x[8]
    assert np.array_equal(stemmed_vessel(gen, np.random.default_rng(3)), stemmed_vessel(gen, np.random.default_rng(3)))


@pytest.mark.slow
def test_the_segmenter_learns_and_round_trips(tmp_path, mitsuba_cpu, monkeypatch):
    """A few steps on four photos lower the loss; the weights written and read back (a narrower
    network than the shipped one: its size comes from the file) give the same probabilities and
    train on from where they were (a second stage); a file of another kind is one clear error."""
    import jax

    from ipm.learned import segmenter_training
    from ipm.learned.network import save
    from ipm.learned.segmenter import FORMAT, load, probabilities
    from ipm.learned.segmenter_training import PROFILES, decoded, fit, make_photos

    monkeypatch.setattr(segmenter_training, "WIDTHS", (8, 16, 16))
    settings = PROFILES["smoke"].updated(steps=30, samples=4, held_out=0, learning_rate=3e-3)
    data = make_photos(4, seed=1, spp=4)
    model, meta = fit(settings, 0, data=data)
    first = fit(settings.updated(steps=1), 0, data=data)[1]["final_loss"]
    assert meta["final_loss"] < first and meta["widths"] == [8, 16, 16]
    save(model, tmp_path / "seg.json", meta, FORMAT)
    back = load(str(tmp_path / "seg.json"))
    images = decoded(data)
    p1, p2 = probabilities(model, images), probabilities(back, images)
    assert p1.shape == data["mask"].shape and np.abs(p1 - p2).max() < 2e-2  # float16 storage
    assert jax.tree_util.tree_structure(model) == jax.tree_util.tree_structure(back)
    from ipm.learned.segmenter import read

    again, again_meta = fit(settings.updated(steps=1), 0, data=data, init=read(tmp_path / "seg.json"))
    assert again_meta["final_loss"] < first and again_meta["init"]["final_loss"] == meta["final_loss"]
    assert again_meta["widths"] == [8, 16, 16] and again_meta["photos"] == [[0, 4]]
    stem = make_photos(2, seed=1, spp=4, stemmed=True)  # a share of every batch from vessels on a stem
    mixed = fit(settings.updated(steps=2), 0, data=data, stemmed=stem, stemmed_share=0.5)[1]
    assert mixed["stemmed_photos"] == [[0, 2]] and mixed["stemmed_share"] == 0.5 and np.isfinite(mixed["final_loss"])
    with pytest.raises(UserError, match="reads 64 px photos"):
        fit(settings, 0, data=data, init=(again.__class__(jax.random.PRNGKey(0), (8, 16, 16), 64), {}))
    (tmp_path / "bad.json").write_text('{"format": "ipm-learned-regressor/1"}')
    with pytest.raises(UserError, match="not a segmenter's weights"):
        load(str(tmp_path / "bad.json"))


def test_the_shipped_segmenter_keeps_the_shadow_and_the_ground_out(photo_case):
    """On a photograph-like view of a dev cup (never trained on: the segmenter saw generator
    samples only), the learned mask refined by GrabCut is close to the true mask, and much closer
    than the colour model of the border, which takes the shadow and the ground in."""
    from ipm.segment import mask_from_image, mask_from_photo

    frame = json.loads((photo_case / "transforms.json").read_text())["frames"][0]
    rgb = np.asarray(Image.open(photo_case / frame["file_path"]).convert("RGB"))
    truth = np.asarray(Image.open(photo_case / frame["mask_path"])) > 127
    iou = lambda m: ((m > 0.5) & truth).sum() / ((m > 0.5) | truth).sum()  # noqa: E731
    learned = iou(mask_from_photo(rgb))
    assert learned > 0.9, learned
    from ipm.capture import open_views  # a user's photo: ipm reconstruct --image P --segment learned

    assert iou(open_views(image=photo_case / frame["file_path"], segment="learned").masks[0]) == learned
    with pytest.raises(UserError, match="cannot segment an image of shape"):
        mask_from_photo(rgb[:8])
    try:
        border = iou(mask_from_image(rgb))
    except UserError:
        border = 0.0
    assert learned > border


@pytest.mark.slow
def test_the_photo_rows_segment_the_image_or_take_the_mask(tmp_path, photo_case):
    """``photo_image`` segments the photograph and records that mask's IoU with the true one;
    ``photo_masked`` reads the true mask; both withhold the camera, and the table gives the mask's
    IoU beside the image-only row."""
    from ipm.methods import METHODS
    from ipm.metrics.recovery import camera_recovery

    image = METHODS["photo_image"](photo_case / "transforms.json", tmp_path / "image", generator="dishes",
                                   profile="smoke", progress=False)
    masked = METHODS["photo_masked"](photo_case / "transforms.json", tmp_path / "masked", generator="dishes",
                                     profile="smoke", progress=False)
    assert 0.8 < image["segmentation"]["mask_iou"] <= 1.0 and "segmentation" not in masked
    assert (tmp_path / "image" / "mesh.ply").is_file() and (tmp_path / "masked" / "mesh.ply").is_file()
    assert camera_recovery(image)["mask_iou"] == image["segmentation"]["mask_iou"]
    assert "mask_iou" not in camera_recovery(masked)
    assert METHODS["photo_image"].layout == METHODS["photo_masked"].layout == "photo"


def test_the_shipped_segmenter_is_the_default_budgets_seed_0():
    """``python -m ipm.learned.segmenter_training`` made the shipped file: a changed budget without
    new weights fails here."""
    from dataclasses import asdict

    from ipm.learned.segmenter import FORMAT, SEG_RES, WIDTHS, shipped_path
    from ipm.learned.segmenter_training import PROFILES

    record = json.loads(shipped_path().read_text())
    assert record["format"] == FORMAT and record["seed"] == 0
    assert record["settings"] == asdict(PROFILES["default"])
    assert record["res"] == SEG_RES and tuple(record["widths"]) == WIDTHS


def _glass_on_grey(seed, stem, foot, colour, shadow=None):
    """A noisy grey photo (the masks' shape) of a glass in ``colour``: a bowl at the top, ``stem``
    and ``foot``, a darkened ``shadow``; GrabCut labels that fix the bowl as object and the rest as
    ground (the network leaving out parts it never saw), GrabCut's mask from them, and the bowl."""
    import cv2

    from ipm.segment import _grab_cut

    rng = np.random.default_rng(seed)
    img = np.clip(150 + rng.normal(0, 6, (*stem.shape, 3)), 0, 255)
    y, x = np.mgrid[:stem.shape[0], :stem.shape[1]]
    bowl = (np.hypot((x - 48) / 22, (y - 30) / 14) < 1) & (y >= 30) | ((y >= 18) & (y < 30) & (abs(x - 48) < 22))
    if shadow is not None:
        img[shadow] *= 0.45
    for part in (bowl, stem, foot):
        img[part] = np.asarray(colour) + rng.normal(0, 6, (part.sum(), 3))
    img8 = img.astype(np.uint8)
    labels = np.where(bowl, cv2.GC_FGD, cv2.GC_BGD).astype(np.uint8)
    return img8, labels, _grab_cut(img8, labels) > 0.5, bowl


def test_the_objects_colours_take_back_a_foot_the_network_left_on_the_ground():
    """``ipm.segment._released``: a purple bowl whose stem and foot the labels fix as ground (as
    the network does with parts it never saw) gets them back, and its grey shadow, darker than
    the floor but of its chroma, stays ground."""
    from ipm.segment import _released

    y, x = np.mgrid[:96, :96]
    stem = (y >= 43) & (y < 54) & (abs(x - 48) < 3)
    foot = (np.hypot((x - 48) / 14, (y - 56) / 4) < 1)
    shadow = (np.hypot((x - 70) / 16, (y - 58) / 5) < 1) & ~foot
    img8, labels, mask, bowl = _glass_on_grey(0, stem, foot, (120, 70, 190), shadow)
    assert not (mask & foot).any()
    grown = _released(img8, labels, mask.astype(np.float32)) > 0.5
    truth = bowl | stem | foot
    assert (grown & truth).sum() / (grown | truth).sum() > 0.95
    assert not (grown & shadow).any()


def test_a_foot_beyond_the_release_reach_does_not_colour_the_ground():
    """``ipm.segment._released``: a glass's foot at the end of a long stem, farther from the
    bowl's mask than the release reaches, is joined to it through the stem, so its colour stays
    out of the ground's and the second pass takes it back (``_joined``)."""
    from ipm.segment import _joined, _released

    y, x = np.mgrid[:120, :96]
    stem = (y >= 43) & (y < 74) & (abs(x - 48) < 3)
    foot = np.hypot((x - 48) / 16, (y - 76) / 4) < 1
    img8, labels, mask, bowl = _glass_on_grey(1, stem, foot, (200, 180, 60))
    assert not (mask & foot).any()
    joined = _joined(mask, stem | foot | bowl)
    assert joined[foot].all() and not joined[mask].any() and not joined[~(stem | foot | bowl)].any()
    grown = _released(img8, labels, mask.astype(np.float32)) > 0.5
    truth = bowl | stem | foot
    assert (grown & foot).sum() > 0.9 * foot.sum()
    assert (grown & truth).sum() / (grown | truth).sum() > 0.95
