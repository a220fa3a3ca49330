"""Rasterizer benchmark: our CPU kernels against gsplat's own PyTorch path, interleaved in one process.

Per case (scene, image size, Gaussian count) the candidates run in rounds, one step each per
round, so machine load hits them alike: ours on 1 thread, ours on all numba threads, and,
when gsplat is installed, gsplat's torch rendering on the CPU (nuav2.splat.gsplat_reference).
A step is a forward plus the backward of a weighted photometric/alpha/depth loss. Reported:
wall and process CPU time per step (min and median), the load average around the case, peak
resident memory added by one step, the image difference between the two renderers, our
per-stage times, and the count of Gaussian-pixel contributions with the time per
contribution against this machine's measured arithmetic floor (nuav2.bench.raster_roofline).
"""

from __future__ import annotations

import ctypes
import gc
import os
import platform
import threading
import time
from collections.abc import Callable, Iterable

import numba
import numpy as np
import torch

import nuav2.splat
from nuav2.bench.near_splat_scene import make_near_splat_scene
from nuav2.bench.raster_roofline import evaluations_per_second
from nuav2.bench.street_scene import StreetScene, make_street_scene
from nuav2.splat import _binning, _composite, rasterize
from nuav2.splat._stages import record_stages
from nuav2.splat.gsplat_reference import ReferenceTooLarge, gsplat_installed, rasterize_gsplat_torch

SCENES: dict[str, Callable[..., StreetScene]] = {"street": make_street_scene,
                                                 "near_splats": make_near_splat_scene}
FULL_SIZES = ((480, 270, 100_000), (960, 540, 100_000), (1600, 900, 300_000))
QUICK_SIZES = ((240, 135, 10_000), (480, 270, 30_000))
# gsplat's torch path holds every Gaussian-pixel contribution at once, with autograd's copies:
# about 200 bytes each (near-splat 960x540/100k: 16 M, 3.9 GB; street 1600x900/300k: 44 M,
# 8.4 GB). It is skipped above this many contributions (counted by our own pass, same rules)
# or above GSPLAT_MAX_PAIRS tile-Gaussian pairs (its intersection arrays).
GSPLAT_MAX_CONTRIBUTIONS = 20_000_000
GSPLAT_MAX_PAIRS = 100_000_000
GSPLAT_REPEATS = 2                  # the reference is slow: at most this many timed steps per case
NEAR_M = 0.1
STAGES = ("projection_fwd", "sort", "pack", "binning", "composite_fwd", "composite_bwd", "unpack",
          "projection_bwd")


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _trim_heap() -> None:
    """Give freed heap pages back so the next RSS baseline is honest (glibc only)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class _PeakRss:
    """Samples RSS every millisecond in a thread (the kernels release the GIL)."""

    def __enter__(self):
        _trim_heap()
        self.base = _rss_bytes()
        self.peak = self.base
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, _rss_bytes())
            time.sleep(0.001)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, _rss_bytes())

    @property
    def delta_mb(self) -> float:
        return round((self.peak - self.base) / 2**20, 1)


def _loss_weights(h: int, w: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(h, w, 3, generator=g), torch.rand(h, w, generator=g), torch.rand(h, w, generator=g)


def _ours(params, scene: StreetScene):
    out = rasterize(*params, scene.world_T_cam, scene.K, scene.width, scene.height, near=NEAR_M)
    return out.rgb, out.alpha, out.depth


def _gsplat_within(max_pairs: int) -> Callable:
    def render(params, scene: StreetScene):
        rgb, alpha, depth, _meta = rasterize_gsplat_torch(*params, scene.world_T_cam, scene.K, scene.width,
                                                          scene.height, near=NEAR_M, max_isects=max_pairs)
        return rgb, alpha, depth

    return render


def _pairs_without_slabs(scene: StreetScene) -> int:
    """Tile-Gaussian pairs if every visible Gaussian were binned at once (no occlusion culling):
    what the slab-by-slab binning avoids writing."""
    with torch.no_grad():
        out = rasterize(*scene.tensors(), scene.world_T_cam, scene.K, scene.width, scene.height, near=NEAR_M)
    m2, conics = out.meta["means2d"][0].numpy(), out.meta["conics"][0].numpy()
    depths, radii = out.meta["depths"][0].numpy(), out.meta["radii"][0].numpy()
    order = _binning.depth_order(depths, radii)
    packed = np.empty((len(order), _composite.PACKED_WIDTH), m2.dtype)
    opacities = torch.sigmoid(scene.opacity_logits).numpy()
    _composite.pack_rows(m2, conics, opacities, scene.colors.numpy(), depths, order, packed, 0, len(order))
    alive = np.ones(_binning.n_tiles(scene.width, scene.height), np.uint8)
    return len(_binning.bin_slab(packed, 0, len(order), scene.width, scene.height, alive, 1)[1])


def _render_and_backward(render: Callable, params: list[torch.Tensor], scene: StreetScene, weights):
    rgb, alpha, depth = render(params, scene)
    wr, wa, wd = weights
    ((rgb * wr).sum() + (alpha * wa).sum() + 0.01 * (depth * wd).sum()).backward()
    return rgb.detach(), alpha.detach(), depth.detach()


def _step(render: Callable, scene: StreetScene, weights) -> tuple[float, float, tuple[torch.Tensor, ...]]:
    """One render plus the backward of a weighted loss on fresh leaf tensors: (wall s, CPU s,
    detached images). Only the render and the backward are timed."""
    params = scene.tensors(requires_grad=True)
    c0, w0 = time.process_time(), time.perf_counter()
    images = _render_and_backward(render, params, scene, weights)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    if any(p.grad is None or not torch.isfinite(p.grad).all() for p in params):
        raise FloatingPointError("non-finite gradient in the benchmark scene")
    return wall, cpu, images


def _summary(walls: list[float], cpus: list[float]) -> dict:
    return {"wall_s_min": round(min(walls), 4), "wall_s_median": round(float(np.median(walls)), 4),
            "cpu_s_min": round(min(cpus), 4), "cpu_s_median": round(float(np.median(cpus)), 4),
            "steps": len(walls)}


def _set_threads(n: int) -> None:
    numba.set_num_threads(n)
    torch.set_num_threads(n)


def _image_diff(a: tuple[torch.Tensor, ...], b: tuple[torch.Tensor, ...]) -> dict:
    rgb_a, alpha_a, depth_a = a
    rgb_b, alpha_b, depth_b = b
    depth_rel = (depth_a - depth_b).abs() / depth_b.abs().clamp_min(1.0)
    return {"rgb_max_abs": float((rgb_a - rgb_b).abs().max()),
            "alpha_max_abs": float((alpha_a - alpha_b).abs().max()),
            "depth_max_rel": float(depth_rel.max()),
            "rgb_pixels_over_1e-5": int(((rgb_a - rgb_b).abs() > 1e-5).any(-1).sum())}


def bench_case(scene_name: str, w: int, h: int, n: int, repeats: int, threads: int, reference: bool,
               rates: tuple[float, float], max_contributions: int = GSPLAT_MAX_CONTRIBUTIONS,
               seed: int = 0) -> dict:
    """Interleaved rounds of ours (1 thread, ``threads``) and gsplat's torch path on one case."""
    scene = SCENES[scene_name](n, w, h, seed)
    weights = _loss_weights(h, w, seed)
    load = [round(os.getloadavg()[0], 2)]
    _set_threads(threads)
    with record_stages() as counts:
        ours_images = _step(_ours, scene, weights)[2]              # warm-up; counts of one step
    candidates = {"ours_1_thread": (1, _ours), f"ours_{threads}_threads": (threads, _ours)}
    case: dict = {"scene": scene_name, "w": w, "h": h, "n": n,
                  "tile_pairs": int(counts["tile_pairs"][0]),
                  "tile_pairs_without_slabs": _pairs_without_slabs(scene),
                  "depth_slabs": int(counts["depth_slabs"][0]),
                  "contributions": int(counts["contributions"][0])}
    case["contributions_per_pixel"] = round(case["contributions"] / (w * h), 2)
    ref_note = None
    if reference and case["contributions"] > max_contributions:
        ref_note = (f"skipped: {case['contributions']:,} Gaussian-pixel contributions (budget "
                    f"{max_contributions:,}); gsplat's torch path holds them all, about 200 B each")
    elif reference:
        try:
            _set_threads(threads)
            gsplat = _gsplat_within(GSPLAT_MAX_PAIRS)
            ref_images = _step(gsplat, scene, weights)[2]
            candidates["gsplat_torch"] = (threads, gsplat)
            case["vs_gsplat"] = _image_diff(ours_images, ref_images)
        except ReferenceTooLarge as exc:
            ref_note = str(exc)
    else:
        ref_note = "gsplat is not installed (pip install gsplat==1.5.3, or the dev extra)"
    times: dict[str, tuple[list, list]] = {k: ([], []) for k in candidates}
    best_stages: dict = {}
    for r in range(repeats):
        for name, (n_threads, render) in candidates.items():
            if name == "gsplat_torch" and r >= GSPLAT_REPEATS:
                continue
            _set_threads(n_threads)
            with record_stages() as stages:
                wall, cpu, _ = _step(render, scene, weights)
            times[name][0].append(wall)
            times[name][1].append(cpu)
            if n_threads == threads and render is _ours and cpu <= min(times[name][1]):
                best_stages = stages
    for name in candidates:
        case[name] = _summary(*times[name])
    for name, (n_threads, render) in candidates.items():
        _set_threads(n_threads)
        with _PeakRss() as mem:
            _step(render, scene, weights)
        case[name]["peak_rss_mb"] = mem.delta_mb
    if ref_note:
        case["gsplat_torch"] = {"skipped": ref_note}
    ours = case[f"ours_{threads}_threads"]
    case["stages_ms"] = {k: {"wall": round(1e3 * best_stages[k][0], 2),
                             "cpu": round(1e3 * best_stages[k][1], 2)} for k in STAGES if k in best_stages}
    case["speedup_threads_vs_1"] = round(case["ours_1_thread"]["wall_s_min"] / ours["wall_s_min"], 2)
    if "wall_s_min" in case.get("gsplat_torch", {}):
        case["speedup_vs_gsplat_torch"] = round(case["gsplat_torch"]["wall_s_min"] / ours["wall_s_min"], 1)
    contributions = max(case["contributions"], 1)
    case["ns_per_contribution"] = round(1e9 * ours["wall_s_min"] / contributions, 2)
    case["cpu_ns_per_contribution"] = round(1e9 * ours["cpu_s_min"] / contributions, 2)
    case["floor_s"] = round(2 * contributions / rates[0], 5)
    case["roofline_fraction"] = round(case["floor_s"] / ours["wall_s_min"], 3)
    case["floor_cpu_s"] = round(2 * contributions / rates[1], 5)
    case["roofline_fraction_cpu"] = round(case["floor_cpu_s"] / ours["cpu_s_min"], 3)
    load.append(round(os.getloadavg()[0], 2))
    case["load_avg_1m"] = load
    _set_threads(threads)
    return case


def run_raster_bench(cases: Iterable[tuple[str, int, int, int]], repeats: int = 5, reference: bool = True,
                     max_contributions: int = GSPLAT_MAX_CONTRIBUTIONS, progress: bool = True) -> dict:
    """Benchmark every (scene, w, h, n) case; returns the JSON-ready report (a bar on a terminal,
    a log line every few seconds elsewhere)."""
    from nuav2.progress import progress_bar

    cases = list(cases)
    threads = numba.get_num_threads()
    reference = reference and gsplat_installed()
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    warm = make_street_scene(1000, 64, 48)
    _step(_ours, warm, _loss_weights(48, 64, 0))                   # compile outside the cases
    jit_s = time.perf_counter() - t0
    rates = evaluations_per_second(threads)
    bar = progress_bar(cases, desc="bench raster", disable=not progress)
    results = [bench_case(s, w, h, n, repeats, threads, reference, rates, max_contributions)
               for s, w, h, n in bar]
    return {"bench": "raster", "interleaved": True,
            "step": "forward + backward of sum(w_rgb*rgb) + sum(w_a*alpha) + 0.01*sum(w_d*depth)",
            "threads": threads, "omp_wait_policy": nuav2.splat.OMP_WAIT_POLICY,
            "cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
            "load_avg_1m": [round(load_before, 2), round(os.getloadavg()[0], 2)],
            "first_call_s": round(jit_s, 2), "repeats": repeats,
            "roofline_evals_per_s": round(rates[0], -6), "roofline_evals_per_cpu_s": round(rates[1], -6),
            "gsplat_max_contributions": max_contributions,
            "gsplat_reference": reference, "cases": results}


def default_cases(quick: bool, scenes: Iterable[str] = tuple(SCENES)) -> list[tuple[str, int, int, int]]:
    sizes = QUICK_SIZES if quick else FULL_SIZES
    return [(s, w, h, n) for s in scenes for w, h, n in sizes]
