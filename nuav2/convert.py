"""The conversion pipeline: find logs -> read each -> write one shard per log -> merge.

Logs are independent, so ``workers`` processes each write their own shards; a log that fails
(corrupt file, missing camera, ...) is recorded in the report and the others go on. A rerun
skips logs whose shard is complete (same options), so a killed conversion resumes and ends
with tables byte-identical to an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from nuav2.convert_report import REPORT_FILE, ConvertReport, write_report
from nuav2.executors import EXECUTORS
from nuav2.image_sources import MODES, image_source_for, write_quality_table
from nuav2.nuscenes_db import shards as sh
from nuav2.nuscenes_db.can_bus import CAN_BUS_DIRNAME
from nuav2.nuscenes_db.images import IMAGE_LINKS, NativeImages
from nuav2.nuscenes_db.merge import LOGS_FILE, merge_shards
from nuav2.nuscenes_db.rewrites import (
    DATA_DIRS,
    other_versions_using,
    remove_log_files,
    retire_tables_naming,
    shared_locations,
)
from nuav2.nuscenes_db.scene_names import SceneNameError
from nuav2.nuscenes_db.scene_names import scene_names_for as _scene_names
from nuav2.nuscenes_db.writer import WRITER_FORMAT, WriterOptions, write_log
from nuav2.rig import RigSpecError, load_rig, scaled_side

log = logging.getLogger(__name__)



MIN_IMAGE_SIDE_PX = 8  # a smaller target image holds nothing a mapping model could use
# The largest target image side. JPEG cannot hold more than 65535 px a side, and long before that
# an image stops fitting a worker: at 16384 x 16384 one float32 RGB buffer of the warp or render
# is 3 GiB (and it has several), and the pixel count, 2^28, stays under OpenCV's default read limit
# (2^30). A nuScenes camera (1600 x 900) reaches it at --scale 10.24, an AV2 one (2048 px) at 8.
MAX_IMAGE_SIDE_PX = 16384


class ConvertError(ValueError):
    """The conversion as a whole cannot go on (bad arguments, no log converted)."""


@dataclass(frozen=True)
class ConvertOptions:
    mode: str = "native"
    version: str = "v1.0-nuav2"
    keyframe_hz: float | None = None  # None: every LiDAR sweep (10 Hz in AV2)
    workers: int = 1
    image_link: str = "copy"
    calibration_dir: Path | None = None
    require_cameras: bool = True
    show_progress: bool = True
    rig: str = "nuscenes"  # warp / render: target rig name or spec path (the CLI refuses it in native)
    scale: float = 1.0  # warp / render: target resolution factor
    recon_preset: str = "default"  # render: reconstruction budget preset
    min_confidence: float = 0.0  # render: drop sample times where a camera's confidence is below
    # render: where the reconstruction trains and renders (auto | cpu | cuda, nuav2.splat.device). Not part of
    # the fingerprint: devices differ in float rounding only; each log's report entry names the device used.
    device: str = "auto"
    # Where the logs run (not part of the fingerprint: every executor writes the same shards).
    executor: str = "local"  # "local" processes or "ray" tasks
    ray_address: str | None = None  # None: RAY_ADDRESS, else a local Ray instance of `workers` slots
    cpus_per_task: float | None = None  # Ray: None -> per-mode default (nuav2.executors.ray_tasks)
    memory_per_task_gb: float | None = None  # Ray: None -> per-mode default; 0: do not reserve memory
    gpus_per_task: float | None = None  # Ray: None -> 1 in render mode when the cluster has GPUs, else 0
    max_retries: int = 2  # a log whose worker process (or node) died is retried this many times

    def check(self) -> None:
        if self.mode not in MODES:
            raise ConvertError(f"--mode must be one of {MODES}, got {self.mode!r}")
        if self.image_link not in IMAGE_LINKS:
            raise ConvertError(f"--image-link must be one of {IMAGE_LINKS}, got {self.image_link!r}")
        if self.keyframe_hz is not None and not 0 < self.keyframe_hz < math.inf:
            raise ConvertError(f"--keyframe-hz must be a finite number > 0 Hz, got {self.keyframe_hz}")
        if self.workers < 1:
            raise ConvertError(f"--workers must be >= 1, got {self.workers}")
        self._check_executor()
        if not self.version or "/" in self.version or self.version.startswith("."):
            raise ConvertError(f"--version must be a plain directory name, got {self.version!r}")
        if self.calibration_dir is not None and not Path(self.calibration_dir).is_dir():
            raise ConvertError(f"--calibration {self.calibration_dir}: calibration directory not found")
        if self.mode == "render":
            from nuav2.recon import ReconConfig

            try:
                ReconConfig.preset(self.recon_preset)
            except ValueError as e:
                raise ConvertError(f"--recon-preset: {e}") from e
            if not 0.0 <= self.min_confidence <= 1.0:  # NaN fails too: it would drop nothing
                raise ConvertError(f"--min-confidence must be a number in [0, 1], got {self.min_confidence}")
            self._check_device()
        if self.mode != "native":
            if not 0 < self.scale < math.inf:
                raise ConvertError(f"--scale must be a finite number > 0, got {self.scale}")
            try:
                rig = load_rig(self.rig)
            except RigSpecError as e:
                raise ConvertError(f"--rig: {e}") from e
            self._check_target_size(rig)

    def _check_target_size(self, rig) -> None:
        """Every camera of ``rig`` at ``--scale`` must be MIN_IMAGE_SIDE_PX..MAX_IMAGE_SIDE_PX a side
        (checked before scaling the rig: ``--scale 1e308`` would make an infinite width)."""
        def side(px: int) -> float:  # as CameraSpec.scaled rounds it
            try:
                return scaled_side(px, self.scale)
            except OverflowError:  # an infinite product, or a rig spec's width of hundreds of digits
                return math.inf

        sizes = [(c.channel, side(c.width), side(c.height)) for c in rig.cameras]
        big = sorted((s for s in sizes if max(s[1:]) > MAX_IMAGE_SIDE_PX), key=lambda s: -max(s[1:]))
        if big:
            name, w, h = big[0]
            fmt = ".0f" if max(w, h) < 1e15 else ".3g"
            size = f"{name} {w:{fmt}}x{h:{fmt}} px" if math.isfinite(w) else f"{name} wider than 1e308 px"
            why = f"--rig {self.rig}: {size}" if self.scale == 1 else f"--scale {self.scale:g} makes {size}"
            more = f"; {len(big) - 1} other camera(s) too" if len(big) > 1 else ""
            raise ConvertError(f"{why} (max {MAX_IMAGE_SIDE_PX} px a side{more})")
        small = [name for name, w, h in sizes if min(w, h) < MIN_IMAGE_SIDE_PX]
        if small:
            raise ConvertError(f"--scale {self.scale:g} makes {', '.join(small)} smaller than "
                               f"{MIN_IMAGE_SIDE_PX} px on a side")

    def _check_executor(self) -> None:
        if self.executor not in EXECUTORS:
            raise ConvertError(f"--executor must be one of {EXECUTORS}, got {self.executor!r}")
        if self.executor != "ray":
            for flag, value in (("--ray-address", self.ray_address), ("--cpus-per-task", self.cpus_per_task),
                                ("--memory-per-task", self.memory_per_task_gb),
                                ("--gpus-per-task", self.gpus_per_task)):
                if value is not None:
                    raise ConvertError(f"{flag} applies to --executor ray only")
        for flag, value in (("--cpus-per-task", self.cpus_per_task), ("--gpus-per-task", self.gpus_per_task),
                            ("--memory-per-task", self.memory_per_task_gb),
                            ("--max-retries", self.max_retries)):
            if value is not None and not 0 <= value < math.inf:
                raise ConvertError(f"{flag} must be a finite number >= 0, got {value}")
        if self.cpus_per_task is not None and self.cpus_per_task == 0:
            raise ConvertError("--cpus-per-task must be > 0")
        if self.executor == "ray":
            from nuav2.executors.ray_tasks import RAY_MISSING, ray_available

            if not ray_available():
                raise ConvertError(RAY_MISSING)

    def _check_device(self) -> None:
        """A bad ``--device`` is one line; ``cuda`` is checked here for local workers (this machine),
        on Ray by the driver against the cluster's GPUs and by each task on its node."""
        from nuav2.splat.device import DEVICES, DeviceUnavailable, resolve_device

        if self.device not in DEVICES:
            raise ConvertError(f"--device must be one of {DEVICES}, got {self.device!r}")
        if self.executor == "local" and self.device == "cuda":
            try:
                resolve_device(self.device, knob="--device")
            except DeviceUnavailable as e:
                raise ConvertError(str(e)) from None

    def _rig_key(self) -> str:
        """A rig named by path is identified by its content, so editing the spec redoes the shards."""
        p = Path(self.rig)
        return hashlib.sha256(p.read_bytes()).hexdigest()[:16] if p.suffix and p.is_file() else self.rig

    def _provider_key(self) -> str | None:
        """What produces re-rendered images (config hash), so a changed default redoes the shards."""
        if self.mode == "warp":
            from nuav2.warp.provider import WarpConfig

            return WarpConfig().fingerprint()
        if self.mode == "render":
            from nuav2.recon import ReconConfig

            recon = ReconConfig.preset(self.recon_preset).to_dict()
            recon.pop("device")  # where it runs, like the executor (see ``device`` above)
            cfg = json.dumps(recon, sort_keys=True, default=str)
            return hashlib.sha256(cfg.encode()).hexdigest()[:12]
        return None

    def fingerprint(self) -> str:
        """Hash of everything that changes a shard's content; resume only reuses matching shards."""
        key = {"writer": WRITER_FORMAT, "mode": self.mode, "keyframe_hz": self.keyframe_hz,
               "images": NativeImages(self.image_link).fingerprint() if self.mode == "native" else None,
               "target": None if self.mode == "native" else [self._rig_key(), self.scale],
               "recon": [self.recon_preset, self.min_confidence] if self.mode == "render" else None,
               "provider": self._provider_key(),
               "calibration": str(Path(self.calibration_dir).resolve()) if self.calibration_dir else None,
               "require_cameras": self.require_cameras}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def scene_names_for(log_ids: list[str]) -> dict[str, str]:
    """``scene-NNNN`` per log, stable whatever else is converted (``nuscenes_db.scene_names``)."""
    try:
        return _scene_names(log_ids)
    except SceneNameError as e:
        raise ConvertError(str(e)) from e


def prepare_output_dir(out: Path) -> None:
    """Create OUT (or accept an existing directory) and make sure files can be written in it."""
    if out.exists() and not out.is_dir():
        raise ConvertError(f"{out}: OUT exists and is not a directory")
    if out.is_symlink() and not out.exists():
        raise ConvertError(f"{out}: OUT is a dangling symbolic link (to {os.readlink(out)})")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as e:
        what = "cannot write in" if out.is_dir() else "cannot create"
        raise ConvertError(f"{out}: {what} the output directory ({e.strerror or e})") from None


def written_folders(version: str) -> tuple[str, ...]:
    """The folders of OUT a conversion writes, replaces or removes files in (docs/database.md's layout)."""
    return (version, *DATA_DIRS, "maps", CAN_BUS_DIRNAME, sh.SHARDS_DIRNAME)


def refuse_overlap(src: Path, out: Path, logs: list[Path], version: str) -> None:
    """OUT must lie outside SRC and every log found in it (a nuScenes dataroot written into the AV2
    tree fills a log or a split folder with files), and SRC outside the folders the conversion writes
    in OUT. SRC elsewhere inside OUT is fine (OUT=/data, SRC=/data/av2/train)."""
    out_r = _resolved("OUT", Path(out))
    inputs = [("SRC", Path(src), _resolved("SRC", Path(src)))] + [("log", p, _resolved("log", Path(p)))
                                                                   for p in logs]
    for what, path, path_r in inputs:
        if out_r == path_r or path_r in out_r.parents:
            where = "is" if out_r == path_r else "is inside"
            raise ConvertError(f"OUT {out} {where} {what} {path}: the nuScenes dataroot would be written "
                               f"into the AV2 source; give an OUT outside it")
        if what == "log" and out_r == path_r.parent:
            raise ConvertError(f"OUT {out} is the split folder of log {path}: the nuScenes dataroot would be "
                               f"written among the AV2 logs; give an OUT outside it")
    for name in written_folders(version):
        for what, path, path_r in inputs:
            if path_r == out_r / name or out_r / name in path_r.parents:
                where = "is" if path_r == out_r / name else "is inside"
                raise ConvertError(f"{what} {path} {where} {Path(out) / name}, a folder that converting "
                                   f"into OUT {out} writes and removes files in: give another OUT")


def _resolved(what: str, path: Path) -> Path:
    """``path.resolve()``; a symlink loop or unreadable link is a one-line error naming the path."""
    try:
        return path.resolve()
    except (RuntimeError, OSError) as e:
        raise ConvertError(f"{what} {path}: cannot resolve the path ({e})") from None


def refuse_foreign_tables(folder: Path) -> None:
    """The merge replaces OUT/<version> whole: refuse where that folder holds files nuav2 did not
    write (no ``nuav2_logs.json``), e.g. a real nuScenes ``v1.0-trainval`` beside the new data."""
    if folder.is_dir() and not (folder / LOGS_FILE).is_file() and any(folder.iterdir()):
        raise ConvertError(f"{folder} holds files that nuav2 did not write (it has no {LOGS_FILE}); "
                           f"converting would replace that folder: use another --version or OUT")


def earlier_shards(out: Path, version: str, fingerprint: str, this_run: set[str]) -> dict[str, Path]:
    """Complete shards in OUT of logs outside this run (an earlier run on another split), to merge too.

    A shard made with other options cannot share a database with this run's: refuse, naming them.
    """
    earlier = {x: p for x, p in sh.existing_shards(out, version).items() if x not in this_run}
    other = sorted(x for x, p in earlier.items() if not sh.is_complete(p, fingerprint))
    if other:
        raise ConvertError(
            f"{sh.shard_root(out, version)} holds shards of {len(other)} log(s) converted with other options "
            f"or an older nuav2 ({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}), and one "
            f"database holds logs converted one way. Convert them again with these options (add their "
            f"SRC), use another --version or OUT, or delete those shard directories")
    return earlier


def log_threads(options: ConvertOptions) -> int:
    """Threads one warp-mode log uses: 2 where its worker has two cores to itself (one local worker on
    this machine, or Ray tasks of 2+ CPUs), else 1; the images are the same either way."""
    if options.executor == "ray":
        from nuav2.executors.ray_tasks import task_cpus

        cpus = task_cpus(options)
    else:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        cpus = cores / options.workers
    return 2 if cpus >= 2 else 1


def convert_one_log(log_dir: Path, dataroot: Path, options: ConvertOptions,
                    after_write: Callable[[str], None] | None = None) -> dict:
    """Read, write and save the shard of one log; returns ``{"log_id", "log_dir", "error", "images"}``
    (error None on success). ``after_write(log_id)`` runs between the data files and the shard
    (the executors' fault-injection point).

    Runs in a worker process: every failure of the log becomes a report entry, not an exception.
    """
    log_dir = Path(log_dir)
    try:
        from converters.av2 import read_log

        scene = read_log(log_dir, options.calibration_dir, require_cameras=options.require_cameras)
        out_rig, images = image_source_for(scene, options.mode, Path(dataroot), image_link=options.image_link,
                                           rig=options.rig, scale=options.scale,
                                           recon_preset=options.recon_preset,
                                           min_confidence=options.min_confidence, device=options.device,
                                           progress=options.show_progress and options.workers == 1,
                                           threads=log_threads(options))
        sh.retire_shard(sh.shard_dir(dataroot, options.version, log_dir.name))
        shard = write_log(scene, out_rig, images, Path(dataroot),
                          WriterOptions(keyframe_hz=options.keyframe_hz,
                                        show_progress=options.show_progress and options.workers == 1,
                                        keep_on_failure=sh.files_other_versions_list(
                                            Path(dataroot), options.version, log_dir.name)))
        quality = getattr(images, "by_file", None)
        if quality:
            shard.meta["image_quality"] = dict(sorted(quality.items()))
        if after_write is not None:
            after_write(log_dir.name)
        sh.save_shard(sh.shard_dir(dataroot, options.version, log_dir.name), shard, options.fingerprint())
        n_images = sum(r["fileformat"] != "pcd" for r in shard.tables["sample_data"])
        return {"log_id": log_dir.name, "log_dir": str(log_dir), "error": None, "images": n_images,
                "device": getattr(images, "device", None)}
    except Exception as e:  # noqa: BLE001 - one bad log must not stop the others
        log.debug("log %s failed:\n%s", log_dir, traceback.format_exc())
        return {"log_id": log_dir.name, "log_dir": str(log_dir), "error": f"{type(e).__name__}: {e}"}


def _run(jobs: list[Path], dataroot: Path, options: ConvertOptions) -> list[dict]:
    """Convert ``jobs`` with the chosen executor (local processes or Ray tasks), sorted by log id."""
    from nuav2.executors import run_logs

    return run_logs(jobs, dataroot, options)


def convert_av2(src: Path, out: Path, options: ConvertOptions | None = None) -> ConvertReport:
    """Convert an AV2 split dir (or one log) at ``src`` into a nuScenes dataroot at ``out``.

    The database holds this run's logs and every complete shard already in ``out`` made with the
    same options (e.g. the train split converted earlier into the same OUT).
    """
    from converters.av2 import find_logs

    options = options or ConvertOptions()
    for name, path in (("SRC", src), ("OUT", out)):
        if not str(path):  # a str: Path("") is ".", the current folder (the CLI refuses it too)
            raise ConvertError(f"{name}: empty path")
    options.check()
    out = Path(out)
    logs = find_logs(Path(src))  # a bad SRC fails here, before OUT is created
    refuse_overlap(Path(src), out, logs, options.version)
    refuse_foreign_tables(out / options.version)
    shared = shared_locations(out, [p.name for p in logs])
    if shared:
        raise ConvertError(f"logs {' and '.join(shared[0])} would share one map location (their ids begin "
                           f"with the same 8 hex digits) and overwrite each other's map: convert them "
                           f"into different OUTs")
    created = not out.exists()
    prepare_output_dir(out)
    with _out_lock(out):
        return _convert_into(out, logs, options, created)


@contextlib.contextmanager
def _out_lock(out: Path) -> Iterator[None]:
    """One conversion at a time into OUT: two at once both reported success, the last to merge silently
    replacing the other's database (and pruning the folders the other was writing)."""
    from nuav2.machine_lock import folder_lock

    held = contextlib.ExitStack()
    try:
        held.enter_context(folder_lock(out))
    except BlockingIOError:  # the lock alone: the same error from the work itself is not a busy OUT
        raise ConvertError(f"{out}: another nuav2 convert is writing into this OUT; wait for it to finish "
                           "or give another OUT") from None
    with held:
        yield


def _convert_into(out: Path, logs: list[Path], options: ConvertOptions, created: bool) -> ConvertReport:
    """convert_av2's work once OUT exists and is held."""
    fingerprint = options.fingerprint()
    earlier = earlier_shards(out, options.version, fingerprint, {p.name for p in logs})
    names = scene_names_for([p.name for p in logs] + sorted(earlier))
    report = ConvertReport(dataroot=str(out), version=options.version, scene_names=names,
                           merged_earlier=sorted(earlier))

    jobs = []
    for log_dir in logs:
        try:
            shard = sh.shard_dir(out, options.version, log_dir.name)
        except ValueError as e:  # a name no shard can have: this log fails, the others convert
            report.failed.append({"log_id": log_dir.name, "log_dir": str(log_dir),
                                  "error": f"ValueError: {e}"})
            continue
        if sh.is_complete(shard, fingerprint):
            report.resumed.append(log_dir.name)
        else:
            jobs.append(log_dir)
    clashes = other_versions_using(out, options.version, fingerprint, [j.name for j in jobs])
    if clashes:
        raise ConvertError(
            f"{out} holds {len(clashes)} log(s) of another --version converted with other options "
            f"({', '.join(clashes[:3])}{', ...' if len(clashes) > 3 else ''}); both versions would share "
            f"those logs' image files, and rewriting them would change that version's images: use "
            f"another OUT, or that version's options")
    retire_tables_naming(out / options.version, [j.name for j in jobs])
    if report.resumed:
        log.info("resuming: %d of %d logs already have a complete shard", len(report.resumed), len(logs))
    if earlier:
        log.info("%s also holds %d log(s) converted earlier with the same options; they are merged too",
                 out, len(earlier))
    try:
        results = _run(jobs, out, options)
    except ConvertError:  # the executor could not start (no Ray): leave no empty OUT behind
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()  # only when still empty
        raise
    finally:  # failed, interrupted and replaced logs leave their data folders empty
        prune_empty_dirs(out, DATA_DIRS)
    report.logs = {r["log_id"]: r.pop("summary") for r in results}
    for r in results:
        if r["error"] is None:
            report.converted.append(r["log_id"])
        else:  # the CLI lists failures at the end; the progress line counts them meanwhile
            log.debug("log %s failed: %s", r["log_dir"], r["error"])
            report.failed.append(r)
            # a worker killed mid-log (out of memory) never ran the writer's own cleanup
            remove_log_files(out, options.version, r["log_id"])
    if report.failed:
        prune_empty_dirs(out, DATA_DIRS)
    report.failed.sort(key=lambda r: r["log_id"])

    done = {x: sh.shard_dir(out, options.version, x) for x in report.converted + report.resumed}
    if done:
        done.update(earlier)
    try:
        if done:
            report.table_counts = merge_shards(out, options.version, done, {x: names[x] for x in done})
            quality: dict[str, float] = {}
            for shard_path in done.values():
                quality.update(sh.read_meta(shard_path)["meta"].get("image_quality", {}))
            write_quality_table(out, options.version, quality)
    except BaseException:
        write_report(out, report)
        raise
    if not write_report(out, report):
        raise ConvertError(f"{out / REPORT_FILE}: cannot write the conversion report")
    if not done:
        first = report.failed[0] if report.failed else None
        why = f"{first['log_dir']}: {first['error']}" if first else "no log to convert"
        many = f" ({len(report.failed)} failed; the first" if len(report.failed) > 1 else ""
        raise ConvertError(f"no log converted{many}: {why}{')' if many else ''}; see {out / REPORT_FILE}")
    return report



def prune_empty_dirs(out: Path, names: tuple[str, ...]) -> None:
    """Remove empty folders under ``out/<name>`` (and the folder itself when it ends up empty)."""
    for name in names:
        top = Path(out) / name
        if not top.is_dir():
            continue
        for folder, _, _ in sorted(os.walk(top), key=lambda w: -len(w[0])):
            with contextlib.suppress(OSError):
                os.rmdir(folder)  # fails, as wanted, where files remain
