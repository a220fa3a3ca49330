"""The conversion modes (``nuav2 convert --mode``), in a module light enough for the CLI's parser:
``nuav2.image_sources``, which implements them, loads numba, OpenCV and the writer (about 0.4 s)."""

MODES = ("native", "warp", "render", "truth")
