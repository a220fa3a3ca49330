"""Start-up hook for MapTR's own environment: ``PYTHONPATH=<this directory> python tools/...``.

Installs the nuAV2 location registration (``nuav2_devkit_locations``, beside this file) and
then runs the ``sitecustomize`` this one shadows, if the environment has one, so nothing the
environment sets up at start-up is lost.
"""

import importlib.machinery
import importlib.util
import os
import sys

import nuav2_devkit_locations  # noqa: F401  (installs the registration on import)


def _run_shadowed_sitecustomize():
    here = os.path.dirname(os.path.abspath(__file__))
    rest = [p for p in sys.path if os.path.abspath(p or os.curdir) != here]
    spec = importlib.machinery.PathFinder.find_spec("sitecustomize", rest)
    if spec is not None and spec.loader is not None:
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)


_run_shadowed_sitecustomize()
