"""Which torch device a reconstruction runs on, and moving its state between devices.

``auto`` picks CUDA only where the rasterizer can use it (CUDA *and* gsplat, see
:func:`nuav2.splat.gsplat_backend.gsplat_available`): CUDA tensors without gsplat would be
copied to the CPU kernels and back on every render, slower than staying on the CPU. Asking
for ``cuda`` where that is not possible is one error naming the knob, not a silent fallback.

Checkpoints and saved scenes hold CPU tensors (:func:`to_cpu`) and are read with
``map_location``, so a run checkpointed on a GPU resumes on a CPU-only node and vice versa.
"""

from __future__ import annotations

import re

import torch

DEVICES = ("auto", "cpu", "cuda")  # what users choose; "cuda:N" is accepted too (a Ray task's own GPU)
_CUDA_INDEX = re.compile(r"^cuda:\d+$")


class DeviceUnavailable(ValueError):
    """The device asked for cannot run the reconstruction here (one line, naming the knob)."""


def check_device_name(name: str, knob: str = "ReconConfig.device") -> None:
    """ValueError unless ``name`` is auto, cpu, cuda or cuda:N."""
    if name not in DEVICES and not _CUDA_INDEX.match(str(name)):
        raise ValueError(f"{knob} must be one of {DEVICES} (or cuda:N), got {name!r}")


def resolve_device(name: str, knob: str = "ReconConfig.device") -> torch.device:
    """The torch device for ``name``: auto -> CUDA when gsplat can rasterize there, else CPU."""
    from nuav2.splat.gsplat_backend import gsplat_available

    check_device_name(name, knob)
    if name == "cpu":
        return torch.device("cpu")
    ok, why = gsplat_available()
    if name == "auto":
        return torch.device("cuda") if ok else torch.device("cpu")
    asked = f"{knob} {name}" if knob.startswith("--") else f"{knob}={name!r}"
    if not ok:
        raise DeviceUnavailable(f"{asked} needs a CUDA GPU and the gsplat package: {why}; "
                                f"use auto or cpu to train on the CPU")
    dev = torch.device(name)
    if dev.index is not None and dev.index >= torch.cuda.device_count():
        raise DeviceUnavailable(f"{asked}: this process sees {torch.cuda.device_count()} CUDA device(s)")
    return dev


def device_label(device: torch.device | str) -> str:
    """What a report records: ``cpu`` or ``cuda:N`` (the index this process sees)."""
    dev = torch.device(device)
    if dev.type == "cuda" and dev.index is None:
        dev = torch.device("cuda", torch.cuda.current_device())
    return str(dev)


def to_cpu(obj):
    """``obj`` with every tensor inside (dicts, lists, tuples) copied to the CPU, detached."""
    return move(obj, torch.device("cpu"))


def move(obj, device: torch.device | str):
    """``obj`` with every tensor inside (dicts, lists, tuples) on ``device``, detached."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().to(device)
    if isinstance(obj, dict):
        return {k: move(v, device) for k, v in obj.items()}
    if isinstance(obj, list):
        return [move(v, device) for v in obj]
    if type(obj) is tuple:
        return tuple(move(v, device) for v in obj)
    return obj
