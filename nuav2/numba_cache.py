"""Where numba caches compiled kernels when it cannot use its own places.

numba caches ``cache=True`` kernels beside the module (``__pycache__``) or in the user's cache
folder (``~/.cache/numba``). In a container run as an arbitrary user neither is writable, and
numba then raises at import ("cannot cache function ...: no locator available"), so even
``nuav2 --help`` failed. Only then ``NUMBA_CACHE_DIR`` is pointed at a per-user temp folder; it
must be set before numba is first imported (``nuav2/__init__.py`` does it).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping


def writable_dir(path: str) -> bool:
    """True when files can be created in ``path`` (created if missing)."""
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            return True
    except OSError:
        return False


def may_write_in(path: str) -> bool:
    """Whether ``path`` (or, where it does not exist yet, its nearest existing ancestor) is a folder
    this process may write in: permission bits only, so the common case writes nothing at import."""
    while not os.path.exists(path) and os.path.dirname(path) != path:
        path = os.path.dirname(path)
    return os.path.isdir(path) and os.access(path, os.W_OK | os.X_OK)


def fallback_cache_dir(package_dir: str, env: Mapping[str, str]) -> str | None:
    """The ``NUMBA_CACHE_DIR`` to set, or None where numba's own places work (or one is set)."""
    if env.get("NUMBA_CACHE_DIR") or may_write_in(os.path.join(package_dir, "__pycache__")):
        return None
    user_cache = os.path.join(env.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "numba")
    if writable_dir(user_cache):
        return None
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return os.path.join(tempfile.gettempdir(), f"nuav2-numba-{uid}")
