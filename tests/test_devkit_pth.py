"""``nuav2 devkit-hook install``: unmodified devkit code opens nuAV2 maps without ``import nuav2``.

Each check runs a fresh interpreter that processes a site directory (as site-packages is at start-up)
and never imports nuav2; without the ``.pth`` the same code must fail with the devkit's own error.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from e2e_helpers import VERSION, cli

from nuav2.devkit_pth import PTH_NAME, pth_line

pytest_plugins = ["test_writer_support", "e2e_support"]

OPEN_MAP = f"""
import json, site, sys
site.addsitedir(sys.argv[1])
from nuscenes.map_expansion.map_api import NuScenesMap
location = json.load(open(sys.argv[2] + '/{VERSION}/log.json'))[0]['location']
nmap = NuScenesMap(sys.argv[2], map_name=location)
print(json.dumps({{"lanes": len(nmap.lane), "nuav2_imported": 'nuav2' in sys.modules}}))
"""


def open_map(site_dir: Path, db: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", OPEN_MAP, str(site_dir), str(db)],
                          capture_output=True, text=True, timeout=300)


def test_installed_hook_opens_nuav2_maps_without_importing_nuav2(native_synth_db: Path, tmp_path: Path):
    site_dir = tmp_path / "site"
    site_dir.mkdir()
    before = open_map(site_dir, native_synth_db)
    assert before.returncode != 0 and "Unknown map name" in before.stderr  # the devkit's own assertion

    code, out, err = cli("devkit-hook", "install", "--site-dir", site_dir)
    assert code == 0, err
    assert json.loads(out)["installed"] == str(site_dir / PTH_NAME)
    after = open_map(site_dir, native_synth_db)
    assert after.returncode == 0, after.stderr
    result = json.loads(after.stdout)
    assert result["lanes"] > 0 and result["nuav2_imported"] is False
    assert after.stderr == ""

    code, out, _ = cli("devkit-hook", "status", "--site-dir", site_dir)
    state = json.loads(out)
    assert code == 0 and state["installed"] == str(site_dir / PTH_NAME) and state["current"] is True
    code, out, _ = cli("devkit-hook", "uninstall", "--site-dir", site_dir)
    assert code == 0 and not (site_dir / PTH_NAME).exists()
    assert open_map(site_dir, native_synth_db).returncode != 0


def test_a_hook_whose_file_is_gone_does_nothing(tmp_path: Path):
    """nuav2 removed but the .pth left behind: interpreters start silently."""
    (tmp_path / PTH_NAME).write_text(pth_line(tmp_path / "gone" / "nuav2_devkit_locations.py"))
    proc = subprocess.run([sys.executable, "-c", "import site, sys; site.addsitedir(sys.argv[1]); "
                           "print('nuav2_devkit_locations' in sys.modules)", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == "False" and proc.stderr == ""


def test_a_site_dir_that_is_not_a_directory_is_one_line(tmp_path: Path):
    code, _, err = cli("devkit-hook", "install", "--site-dir", tmp_path / "missing")
    assert code == 2 and err.strip().count("\n") == 0 and "--site-dir" in err


def test_status_flags_a_hook_left_by_another_checkout(tmp_path: Path):
    (tmp_path / PTH_NAME).write_text(pth_line(tmp_path / "old_checkout" / "nuav2_devkit_locations.py"))
    code, out, err = cli("devkit-hook", "status", "--site-dir", tmp_path)
    assert code == 1 and json.loads(out)["current"] is False and "install" in err


def test_a_read_only_site_dir_is_one_line_naming_the_flag(tmp_path: Path):
    from e2e_helpers import cli_bound_by_modes

    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    code, _, err = cli_bound_by_modes("devkit-hook", "install", "--site-dir", locked)
    assert code == 2 and err.strip().count("\n") == 0, err
    assert f"--site-dir {locked}" in err and ".tmp" not in err
    assert list(locked.iterdir()) == []
