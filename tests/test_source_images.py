"""Source images decoded at a reduced size where a JPEG allows it exactly (issue 13's speed item)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from converters.av2 import read_log
from nuav2.image_decode import jpeg_reduction, load_image_u8
from nuav2.splat.views import source_views
from nuav2.synth import SynthConfig, generate_log


def test_reduction_factor_divides_the_image_exactly_and_keeps_the_training_size():
    jpg = Path("ring_front_center/315.jpg")
    assert jpeg_reduction(jpg, (2048, 1550), 256, 194) == 2  # 1550 / 4 is not whole: the grid would shift
    assert jpeg_reduction(jpg, (2048, 1552), 256, 194) == 8
    assert jpeg_reduction(jpg, (2048, 1552), 512, 388) == 4
    assert jpeg_reduction(jpg, (2047, 1550), 256, 194) == 1
    assert jpeg_reduction(jpg, (256, 194), 256, 194) == 1  # the synthetic logs' 1/8 images
    assert jpeg_reduction(Path("a.png"), (2048, 1552), 256, 194) == 1  # only JPEG decodes smaller
    assert jpeg_reduction(jpg, None, 256, 194) == 1


@pytest.fixture(scope="module")
def quarter_log(tmp_path_factory) -> Path:
    """A 0.1 s synthetic log at a quarter of AV2's resolution (512x388 ring cameras)."""
    config = SynthConfig(seconds=0.1, image_scale=0.25)
    return generate_log(tmp_path_factory.mktemp("quarter"), seed=0, config=config)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return 10 * np.log10(255**2 / max(mse, 1e-12))


def test_a_reduced_decode_matches_the_full_decode_resized(quarter_log):
    views = source_views(read_log(quarter_log), 0.5)
    assert {v.source_size for v in views} == {(512, 388), (388, 512)}  # ring cameras; the portrait front
    for v in views[:: max(1, len(views) // 6)]:
        assert jpeg_reduction(v.path, v.source_size, v.cam.width, v.cam.height) == 2
        fast = v.image_u8()
        full = load_image_u8(v.path, v.cam.width, v.cam.height)  # whole file decoded, area-resized
        assert fast.shape == full.shape == (v.cam.height, v.cam.width, 3) and fast.dtype == np.uint8
        assert psnr(fast, full) > 40.0
        assert abs(float(fast.mean()) - float(full.mean())) < 0.5  # no brightness or colour shift


def test_warp_exposure_reads_its_small_images_the_same_exact_way(quarter_log):
    from nuav2.warp.harmonise import read_reduced

    scene = read_log(quarter_log)
    cam = scene.rig.camera("ring_front_left")
    frame = scene.camera_frames["ring_front_left"][0]
    img, small = read_reduced(Path(frame.path), cam, width_px=128)
    assert (small.width, small.height) == (128, 97) and img.shape == (97, 128, 3)
    assert jpeg_reduction(frame.path, (cam.width, cam.height), small.width, small.height) == 4
    assert psnr(img, load_image_u8(Path(frame.path), small.width, small.height)) > 35.0


def test_an_image_read_for_the_exposure_solve_is_corrected_without_a_second_decode(quarter_log, monkeypatch):
    import nuav2.splat.views as views_module
    from nuav2.exposure import ExposureModel

    decodes: list[Path] = []
    real = views_module.load_image_u8

    def counted(path, *args):
        decodes.append(Path(path))
        return real(path, *args)

    monkeypatch.setattr(views_module, "load_image_u8", counted)
    views = source_views(read_log(quarter_log), 0.5)[:4]
    raw = [v.raw_image_u8().copy() for v in views]  # what the exposure solve reads, before a model exists
    n = len(views)
    gains = np.tile([[0.3, -0.2, 0.1]], (n, 1))
    model = ExposureModel(gains, np.array([[-0.2, 0.05]]), np.zeros(n, np.int64))
    for v in views:
        v.set_exposure(model)
    for v, r in zip(views, raw, strict=True):
        assert np.array_equal(v.raw_image_u8(), r)  # still the camera's pixels
        corrected = v.image_u8()
        assert np.array_equal(corrected, model.correct(r, v.index, v.cam.K))
        assert not np.array_equal(corrected, r)
    assert len(decodes) == n  # each file read once
    v = views[0]
    assert np.array_equal(v.raw_image_u8(), raw[0]) and len(decodes) == n + 1  # later raw reads decode again


def test_a_jpeg_cut_short_is_refused_by_the_warp_and_render_readers(quarter_log, tmp_path: Path):
    """cv2 decodes a truncated JPEG without an error (its missing rows grey); native mode's decode
    check caught it, warp and render modes converted the grey rows until they checked the end marker.
    Bytes after the marker (padding, a trailer) and other formats under a .jpg name stay readable."""
    import cv2

    from nuav2.image_decode import jpeg_cut_short
    from nuav2.nuscenes_db.images import ImageSourceError, decode_problem
    from nuav2.warp.harmonise import read_reduced
    from nuav2.warp.provider import read_rgb

    scene = read_log(quarter_log)
    frame = next(iter(scene.camera_frames.values()))[0]
    cam = scene.rig.camera(frame.channel)
    whole = Path(frame.path).read_bytes()
    assert not jpeg_cut_short(whole)
    for keep in (len(whole) * 3 // 4, len(whole) - 2, 300):
        cut = tmp_path / "cut.jpg"
        cut.write_bytes(whole[:keep])
        assert jpeg_cut_short(cut.read_bytes()) and decode_problem(cut) is not None, keep
        with pytest.raises(ImageSourceError, match="cut.jpg: camera image cut short"):
            read_rgb(cut, cam)
        with pytest.raises(ValueError, match="cut.jpg: camera image cut short"):
            load_image_u8(cut, cam.width // 2, cam.height // 2, (cam.width, cam.height))
        with pytest.raises(ImageSourceError, match="cut.jpg: camera image cut short"):
            read_reduced(cut, cam)  # warp's exposure solve, which reads the images first
    png = cv2.imencode(".png", cv2.imread(frame.path))[1].tobytes()
    for name, data in (("zeros", whole + b"\x00" * 16), ("crlf", whole + b"\r\n" * 40),
                       ("ff", whole + b"\xff" * 8), ("trailer", whole + bytes(range(256)) * 2),
                       ("png", png)):
        ok = tmp_path / f"{name}.jpg"
        ok.write_bytes(data)
        assert not jpeg_cut_short(data) and decode_problem(ok) is None, name
        assert np.array_equal(read_rgb(ok, cam), read_rgb(Path(frame.path), cam)), name
    # A thumbnail's own markers (an APP1 segment holding a whole small JPEG) do not end the image.
    thumb = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    app1 = b"\xff\xe1" + (len(thumb) + 2).to_bytes(2, "big") + thumb
    with_thumb = whole[:2] + app1 + whole[2:]
    assert not jpeg_cut_short(with_thumb)
    assert jpeg_cut_short(with_thumb[: len(with_thumb) * 3 // 4])
