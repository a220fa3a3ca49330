"""Source images decoded at a reduced size where a JPEG allows it exactly (issue 13's speed item)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from converters.av2 import read_log
from nuav2.splat.views import jpeg_reduction, load_image_u8, source_views
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


def test_a_reduced_decode_matches_the_full_decode_resized(tmp_path):
    log = generate_log(tmp_path, seed=0, config=SynthConfig(seconds=0.1, image_scale=0.25))
    views = source_views(read_log(log), 0.5)
    assert {v.source_size for v in views} == {(512, 388), (388, 512)}  # ring cameras; the portrait front
    for v in views[:: max(1, len(views) // 6)]:
        assert jpeg_reduction(v.path, v.source_size, v.cam.width, v.cam.height) == 2
        fast = v.image_u8()
        full = load_image_u8(v.path, v.cam.width, v.cam.height)  # whole file decoded, area-resized
        assert fast.shape == full.shape == (v.cam.height, v.cam.width, 3) and fast.dtype == np.uint8
        mse = float(np.mean((fast.astype(np.float64) - full) ** 2))
        assert 10 * np.log10(255**2 / max(mse, 1e-12)) > 40.0
        assert abs(float(fast.mean()) - float(full.mean())) < 0.5  # no brightness or colour shift
