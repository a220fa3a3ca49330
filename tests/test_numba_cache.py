"""numba's kernel cache falls back to a temp folder only where its own places are not writable."""

from __future__ import annotations

import os
from pathlib import Path

from nuav2.numba_cache import fallback_cache_dir


def test_the_fallback_is_used_only_where_numba_has_nowhere_to_write(tmp_path: Path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")  # a folder below a regular file can never be created
    package, home = str(tmp_path / "pkg"), str(tmp_path / "home")
    assert fallback_cache_dir(package, {"XDG_CACHE_HOME": home}) is None
    assert fallback_cache_dir(str(blocker / "pkg"), {"XDG_CACHE_HOME": home}) is None  # the user cache
    fallback = fallback_cache_dir(str(blocker / "pkg"), {"XDG_CACHE_HOME": str(blocker / "cache")})
    assert fallback is not None and Path(fallback).parent == Path(os.environ.get("TMPDIR", "/tmp"))
    assert fallback_cache_dir(str(blocker / "pkg"), {"NUMBA_CACHE_DIR": "/x"}) is None  # the user's own
