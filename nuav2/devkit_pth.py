"""An opt-in ``.pth`` start-up hook: every Python process of an environment gets the devkit registration.

Without it, unmodified nuScenes scripts in nuav2's environment must ``import nuav2`` (or run with
``PYTHONPATH=nuav2/devkit_hook``) before ``NuScenesMap(dataroot, map_name=log['location'])`` accepts
a nuAV2 location. A ``.pth`` file in site-packages runs one line at interpreter start; ours loads the
standalone registration file (``devkit_hook/nuav2_devkit_locations.py``) by path: standard library
only (~15 ms), nothing of nuav2 itself (no environment variables set, no numba, no torch), and the
devkit patches stay lazy (applied when the devkit is imported). If nuav2 is removed, the line finds
no file and does nothing.
"""

from __future__ import annotations

import sysconfig
from pathlib import Path

from nuav2.atomic import atomic_file
from nuav2.devkit_compat import HOOK_DIR, MODULE_NAME

PTH_NAME = "nuav2_devkit_hook.pth"


def pth_line(hook_file: Path = HOOK_DIR / f"{MODULE_NAME}.py") -> str:
    """The one line site.py executes (it runs lines that start with ``import``)."""
    body = (f"p = {str(hook_file)!r}\n"
            f"if os.path.isfile(p) and {MODULE_NAME!r} not in sys.modules:\n"
            f"    s = importlib.util.spec_from_file_location({MODULE_NAME!r}, p)\n"
            f"    m = importlib.util.module_from_spec(s)\n"
            f"    sys.modules[{MODULE_NAME!r}] = m\n"
            f"    s.loader.exec_module(m)\n")
    scope = "{'importlib': importlib, 'os': os, 'sys': sys}"
    return f"import importlib.util, os, sys; exec({body!r}, {scope})\n"


def default_site_dir() -> Path:
    """This environment's site-packages (the purelib directory pip installs into)."""
    return Path(sysconfig.get_paths()["purelib"])


def install(site_dir: Path | None = None) -> Path:
    """Write the ``.pth`` into ``site_dir`` (default: this environment's site-packages); returns its path."""
    path = (site_dir or default_site_dir()) / PTH_NAME
    with atomic_file(path) as f:
        f.write(pth_line().encode())
    return path


def uninstall(site_dir: Path | None = None) -> Path | None:
    """Remove the ``.pth``; returns its path, or None if there was none."""
    path = (site_dir or default_site_dir()) / PTH_NAME
    if not path.exists():
        return None
    path.unlink()
    return path


def status(site_dir: Path | None = None) -> dict:
    """Whether the ``.pth`` is there and whether it is this installation's line (a ``.pth`` left by a
    checkout that moved or was removed does nothing)."""
    path = (site_dir or default_site_dir()) / PTH_NAME
    if not path.is_file():
        return {"installed": None, "current": False}
    try:
        current = path.read_text() == pth_line()
    except (OSError, UnicodeDecodeError):
        current = False
    return {"installed": str(path), "current": current,
            "hook_file": str(HOOK_DIR / f"{MODULE_NAME}.py")}
