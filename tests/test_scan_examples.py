"""The synthetic phone photos of ``rectify example`` / ``scan example`` (:mod:`mi_svbrdf.data.scan_examples`):
4032 x 3024 JPEG with the sample well over 1024 px across and a material as fine, rendered once and cached; one
full-size photo of each kind rendered and rectified to 1024^2 with sub-pixel corners and real detail."""
from __future__ import annotations

import doctest
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mi_svbrdf.data import scan_examples as SE
from mi_svbrdf.data.frame_photos import photo_pipeline
from mi_svbrdf.data.frame_photos import project as project_frame
from mi_svbrdf.geometry.poses import focal_35mm_of
from mi_svbrdf.io.material_io import srgb_encode

#: The sample plane's window ``[-1, 1]^2``: its corners.
WINDOW = np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0]])
#: A small size for the tests of the cache (the photos' own size is checked without rendering them all).
SMALL = (320, 240)


def _shortest_side(uv: np.ndarray) -> float:
    return float(min(np.linalg.norm(uv[i] - uv[(i + 1) % 4]) for i in range(4)))


def _quantization(quality: int) -> dict:
    """The JPEG quantization tables Pillow writes at ``quality``."""
    import io

    buf = io.BytesIO()
    Image.new("RGB", (16, 16)).save(buf, format="JPEG", quality=quality)
    return Image.open(buf).quantization


def test_the_photos_are_phone_sized_with_the_sample_well_over_1024_px_and_as_many_texels() -> None:
    """The configured size, format and material, and each camera's view of the sample (projected, not rendered)."""
    assert SE.PHOTO_SIZE == SE.PHONE_SIZE == (4032, 3024) and SE.JPEG_QUALITY == 92
    assert SE.photo_names("tags") == [f"IMG_{k:04d}.jpg" for k in range(5)] and len(SE.photo_names("frame")) == 3
    for kind in SE.KINDS:
        s = SE.settings(kind)
        assert s["photo_size"] == [4032, 3024] and s["jpeg_quality"] == 92 and s["material_texels"] >= 1500
    tag_sides = [_shortest_side(c.project(WINDOW)) for c in SE.tag_cameras()]
    frame_sides = [_shortest_side(project_frame(p, WINDOW)) for p in SE.frame_poses()]
    assert min(tag_sides + frame_sides) > 1200, (tag_sides, frame_sides)
    # the material has at least as many texels across the sample as the nearest photo has pixels
    longest = max(max(np.linalg.norm(np.roll(c.project(WINDOW), -1, 0) - c.project(WINDOW), axis=1))
                  for c in SE.tag_cameras())
    assert SE.settings("tags")["material_texels"] >= longest
    # the paper frame's EXIF focal length (whole mm, as EXIF stores it) is exactly the rendered FOV's
    for pose in SE.frame_poses():
        f35 = focal_35mm_of(pose.fov_deg, 4032, 3024)
        assert f35 == pytest.approx(round(f35), abs=1e-6) and 20 <= f35 <= 60
    # smaller photos: the same cameras, scaled
    small = SE.tag_cameras(size=(1008, 756))
    assert [c.matrix[0, 0] * 4 for c in small] == pytest.approx([c.matrix[0, 0] for c in SE.tag_cameras()])
    assert doctest.testmod(SE).failed == 0


def test_a_set_is_rendered_once_then_copied_from_the_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))
    first = SE.example_photos("frame", tmp_path / "a", SMALL)
    cached = SE.cache_folder("frame", SMALL)
    assert cached.parent == tmp_path / "cache" / "scan_examples" and cached.name.startswith("frame-")
    assert [p.name for p in first] == SE.photo_names("frame") and sorted(p.name for p in cached.iterdir()) == [
        p.name for p in first]
    for path in first:
        with Image.open(path) as img:
            assert img.format == "JPEG" and img.size == SMALL and img.mode == "RGB"
            assert img.quantization == _quantization(SE.JPEG_QUALITY)
            assert img.getexif().get_ifd(0x8769).get(41989)  # FocalLengthIn35mmFilm: rectify's FOV
    # again: copied, nothing rendered; a photo missing from the cache (an interrupted set): that one alone
    rendered: list[int] = []
    real = SE.render_photo

    def counting(kind: str, index: int, *args: object, **kwargs: object) -> Path:
        rendered.append(index)
        return real(kind, index, *args, **kwargs)

    monkeypatch.setattr(SE, "render_photo", counting)
    again = SE.example_photos("frame", tmp_path / "b", SMALL)
    assert rendered == [] and [p.read_bytes() for p in again] == [p.read_bytes() for p in first]
    (cached / "IMG_0001.jpg").unlink()
    third = SE.example_photos("frame", tmp_path / "c", SMALL)
    assert rendered == [1] and [p.read_bytes() for p in third] == [p.read_bytes() for p in first]  # deterministic
    # the key: every setting and the version
    assert SE.cache_folder("frame", (640, 480)) != cached and SE.cache_folder("tags", SMALL) != cached
    monkeypatch.setattr(SE, "VERSION", SE.VERSION + 1)
    assert SE.cache_folder("frame", SMALL) != cached
    # the tag photos: no EXIF (the camera is calibrated from the tags); without the cache, straight into the folder
    tags = SE.example_photos("tags", tmp_path / "t", SMALL, cache=False)
    assert len(tags) == 5 and not list((tmp_path / "cache" / "scan_examples").glob("tags-*"))
    with Image.open(tags[0]) as img:
        assert img.size == SMALL and not img.getexif().get_ifd(0x8769)
    # a cache that cannot be written (MI_SVBRDF_CACHE names a file): rendered straight into the folder
    (tmp_path / "not_a_folder").write_text("")
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "not_a_folder"))
    assert [p.read_bytes() for p in SE.example_photos("tags", tmp_path / "u", SMALL)] == [p.read_bytes() for p in tags]
    with pytest.raises(ValueError, match="kind: expected one of"):
        SE.settings("paper")


def test_the_photo_pipeline_is_the_srgb_encoding_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    radiance = (rng.random((300, 7, 3), dtype=np.float32) * 1.2 - 0.05).astype(np.float32)
    noise = np.random.default_rng(5).normal(0.0, 0.01, radiance.shape).astype(np.float32)
    expected = np.clip(np.rint(srgb_encode(np.clip(radiance + noise, 0.0, 1.0)) * 255.0), 0, 255).astype(np.uint8)
    assert np.array_equal(photo_pipeline(radiance, 0.01, 5), expected)


@pytest.mark.parametrize("kind", SE.KINDS)
def test_a_full_size_photo_rectifies_to_1024_with_sub_pixel_corners_and_real_detail(kind: str,
                                                                                    tmp_path: Path) -> None:
    """One 12 MP photo of each kind (rendered here, no cache), rectified to 1024^2 (the camera from --fov 60 for the
    tags, from EXIF for the paper frame): the corners within a fraction of a pixel, the camera where it was, and
    the leather's grain in the rectified photo (what a 2x2 box blur takes away from it: real detail, not upsampled
    blur)."""
    from mi_svbrdf.geometry.rectify import RectifyOptions, rectify_photos
    from mi_svbrdf.geometry.tag_rectify import rectify_tag_photos
    from mi_svbrdf.geometry.tags import TagSheet

    photo = SE.render_photo(kind, 0, tmp_path / "IMG_0000.jpg", SE.material())
    with Image.open(photo) as img:
        assert img.size == (4032, 3024) and img.format == "JPEG"
    out = tmp_path / "rect"
    if kind == "tags":
        truth = SE.tag_cameras(1)[0]
        results = rectify_tag_photos([photo], out, RectifyOptions(size=1024, fov_deg=SE.TAG_FOV),
                                     TagSheet(SE.TAG_SHEET_MM))
        entry = results[0].entry
        assert entry["reprojection_error_px"]["tags_rms"] < 0.2, entry["reprojection_error_px"]
        true_position = truth.position
    else:
        pose = SE.frame_poses(1)[0]
        results = rectify_photos([photo], out, RectifyOptions(size=1024))
        entry = results[0].entry
        assert np.abs(np.asarray(entry["corners_px"]) - project_frame(pose, WINDOW)).max() < 0.3
        true_position = np.asarray(pose.camera)
    assert results[0].ok, results[0].error
    error = np.linalg.norm(np.asarray(entry["camera_position"]) - true_position) / np.linalg.norm(true_position)
    assert error < 0.01, error
    grey = np.asarray(Image.open(out / entry["output"]).convert("L"), np.float64)
    assert grey.shape == (1024, 1024)
    box = grey[:1024, :1024].reshape(512, 2, 512, 2).mean(axis=(1, 3)).repeat(2, axis=0).repeat(2, axis=1)
    assert np.sqrt(np.mean((grey - box) ** 2)) > 3.0  # of 255 (about 5; 640 x 480 photos upsampled: 1.3-1.7)
    assert json.loads((out / "rectify.json").read_text())["photos"][0]["size_hw"] == [3024, 4032]
