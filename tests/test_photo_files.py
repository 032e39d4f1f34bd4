"""A photograph as a user brings it: turned by its Exif orientation, in any pixel format, at any
size (``ipm.segment``: a large photo segmented at a bounded size) and framing (a small object
segmented again in a crop about it)."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from ipm.photo import photo_views


def test_a_photo_is_read_as_a_viewer_shows_it(tmp_path, tiny_case):
    """A phone's portrait photo is stored on its side with an Exif orientation: read upright (its
    size, its alpha mask, its colours), with its focal length turned to the upright width; a grey
    photo is segmented like a colour one, and a one-bit or palette mask reads as its values."""
    from ipm.io.views import load_photos
    from ipm.photo import exif_fov

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    rgb = np.asarray(Image.open(tiny_case / frame["file_path"]).convert("RGB"))[:, 8:56]  # 48 wide, 64 high
    alpha = np.asarray(Image.open(tiny_case / frame["mask_path"]))[:, 8:56]
    upright = Image.fromarray(np.dstack([rgb, alpha]))
    upright.save(tmp_path / "upright.png")
    exif = Image.Exif()
    exif[0x0112] = 6  # stored turned a quarter: a viewer turns it back clockwise
    exif.get_ifd(0x8769)[0xA405] = 26
    upright.transpose(Image.ROTATE_90).save(tmp_path / "stored.png", exif=exif)
    views, plain = photo_views(tmp_path / "stored.png"), photo_views(tmp_path / "upright.png", fov_deg=40.0)
    assert (views.width, views.height) == (48, 64) and np.array_equal(views.masks, plain.masks)
    assert views.fov_x == pytest.approx(exif_fov(26.0, 48, 64)) and exif_fov(26.0, 64, 48) > views.fov_x + 0.1
    as_stored = replace(plain, frames=[{"file_path": str(tmp_path / "upright.png")}])
    np.testing.assert_array_equal(load_photos(views), load_photos(as_stored))
    truth = alpha > 127
    Image.fromarray(np.dstack([rgb, np.full_like(alpha, 255)])).save(tmp_path / "opaque.png")
    Image.fromarray(rgb).convert("L").save(tmp_path / "grey.png")
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "print.jpg", quality=95)
    for name in ("opaque.png", "grey.png", "print.jpg"):  # no alpha that tells: segmented by colour
        found = photo_views(tmp_path / name, fov_deg=40.0).masks[0] > 0.5
        assert (found & truth).sum() / (found | truth).sum() > 0.8, name
    for mode in ("1", "P"):
        Image.fromarray(alpha).convert(mode).save(tmp_path / f"mask_{mode}.png")
        given = photo_views(tmp_path / "upright.png", tmp_path / f"mask_{mode}.png", fov_deg=40.0)
        np.testing.assert_array_equal(given.masks, plain.masks)


def test_a_large_photo_is_segmented_at_a_bounded_size(monkeypatch, tiny_case):
    """A photograph longer than ``SEGMENT_PX`` is segmented by the learned path shrunk to it and its
    mask comes back at the photo's size; a smaller one is segmented as it is."""
    import ipm.learned.segmenter as segmenter
    import ipm.segment as segment

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    rgb = np.asarray(Image.open(tiny_case / frame["file_path"]).convert("RGB"))
    truth = np.asarray(Image.open(tiny_case / frame["mask_path"])) > 127
    seen, probability = [], segmenter.probability
    monkeypatch.setattr(segmenter, "probability", lambda img, model=None: seen.append(img.shape[:2])
                        or probability(img, model))
    small = segment.mask_from_photo(rgb) > 0.5
    large = segment.mask_from_photo(np.kron(rgb, np.ones((12, 12, 1), np.uint8))) > 0.5  # 768 px
    assert seen == [(64, 64), (768, 768), (512, 512)] and large.shape == (768, 768)  # where its object is, its mask
    big_truth = np.kron(truth, np.ones((12, 12), bool))
    assert (large & big_truth).sum() / (large | big_truth).sum() > (small & truth).sum() / (small | truth).sum() - 0.05


def test_a_small_object_is_segmented_again_in_a_crop(monkeypatch, tiny_case, rng):
    """The cup's 64 px view in the middle of a 320 px plain photo: the network reads the whole photo
    at 128 px, finds the object small and the learned path segments a square crop about it again;
    the cup's own 64 px photo needs no crop. ``_crop_box``: 1.5 times the object's box, clipped."""
    import ipm.learned.segmenter as segmenter
    from ipm.segment import CROP, _crop_box, mask_from_photo

    frame = json.loads((tiny_case / "transforms.json").read_text())["frames"][0]
    rgb = np.asarray(Image.open(tiny_case / frame["file_path"]).convert("RGB"))
    truth = np.asarray(Image.open(tiny_case / frame["mask_path"])) > 127
    photo = np.clip(rgb[0, 0] + rng.normal(0, 2, (320, 320, 3)), 0, 255).astype(np.uint8)
    photo[128:192, 128:192] = rgb
    placed = np.zeros((320, 320), bool)
    placed[128:192, 128:192] = truth
    seen, probability = [], segmenter.probability
    monkeypatch.setattr(segmenter, "probability", lambda img, model=None: seen.append(img.shape[:2])
                        or probability(img, model))
    mask = mask_from_photo(photo) > 0.5
    assert mask.shape == (320, 320) and len(seen) == 2 and max(seen[1]) < CROP * 320
    assert (mask & placed).sum() / (mask | placed).sum() > 0.85
    mask_from_photo(rgb)
    assert seen[2:] == [(64, 64)]  # one read: where its object is, and its mask (no crop)
    obj = np.zeros((100, 200), bool)
    obj[40:60, 10:30] = True
    assert _crop_box(obj) == ((35, 65), (5, 35)) and _crop_box(obj[:, :40]) is None and _crop_box(~obj & False) is None
