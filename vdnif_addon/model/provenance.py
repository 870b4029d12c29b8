"""What produced a results file: the commit, today's default network and recipe (with a short
hash of the network), and, where the file holds times, the machine. Every study and tool that
writes a results JSON records it under ``provenance`` (``stamp``), so that a table whose JSON
describes another network than today's default can be told apart: the model format's version
did not change with the normal field, so a model file cannot tell
(``tests/studies/test_results_provenance.py``).

Imports only the settings at load, so that a test reads today's hash cheaply.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import pathlib
import subprocess
import sys
from typing import Any

from .. import settings

REPO = pathlib.Path(__file__).resolve().parents[2]
HASH_DIGITS = 12
UNKNOWN = "unknown"


def commit(repo: str | os.PathLike = REPO) -> str:
    """``git rev-parse HEAD`` of the checkout ``repo``, with ``+modified`` where tracked files
    differ from it; "unknown" outside a checkout (an installed extension) or without git."""
    if not (pathlib.Path(repo) / ".git").exists():    # not a git repository enclosing it
        return UNKNOWN
    try:
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], check=True,
                              capture_output=True, text=True, timeout=10).stdout.strip()
        changed = subprocess.run(["git", "-C", str(repo), "status", "--porcelain",
                                  "--untracked-files=no"], check=True, capture_output=True,
                                 text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return UNKNOWN
    return (head + "+modified" if changed else head) or UNKNOWN


def default_network() -> dict[str, Any]:
    """Today's default network (``settings.NetworkConfig``) without its heads, which follow
    the mesh (an albedo head where it is textured, a material head where it has materials)."""
    network = settings.NetworkConfig().to_dict()
    network.pop("heads")
    return network


def network_hash(network: dict[str, Any] | None = None) -> str:
    """A short hash of a network configuration (default: today's ``default_network``)."""
    text = json.dumps(default_network() if network is None else network, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:HASH_DIGITS]


def default_recipe() -> dict[str, Any]:
    """The recipe's defaults: data sizes, optimization, what the occlusion threshold's
    calibration minimizes, the resolution rules and the secondary rays' start
    (``settings``)."""
    training = settings.TrainConfig().to_dict()
    for key in ("device", "seed"):      # a run's own choices, not the recipe's
        training.pop(key)
    return {
        "data": dataclasses.asdict(settings.RECIPE),
        "training": training,
        "occlusion_calibration": settings.OCCLUSION_CALIBRATION,
        "resolution_rules": {
            "default": settings.RECIPE.resolution,
            "textured": settings.RECIPE.textured_resolution,
            "auto_candidates": list(settings.RESOLUTION_CANDIDATES),
            "knee_margin": settings.KNEE_MARGIN, "knee_tolerance": settings.KNEE_TOLERANCE,
            "embedding_target": settings.EMBEDDING_TARGET,
            "thin_part_voxels": settings.THIN_PART_VOXELS,
            "thin_part_share": settings.THIN_PART_SHARE},
        "secondary": {
            "offset": settings.SECONDARY_OFFSET,
            "offset_voxels": settings.SECONDARY_OFFSET_VOXELS,
            "offset_errors": settings.SECONDARY_OFFSET_ERRORS,
            "grazing_cosine": settings.SECONDARY_GRAZING_COSINE,
            "self_reach": settings.SECONDARY_SELF_REACH,
            "self_cosine": settings.SECONDARY_SELF_COSINE,
            "self_skips": settings.SECONDARY_SELF_SKIPS},
    }


def machine() -> dict[str, Any]:
    """The machine a run's times were measured on: the CPU's model name (as the side-by-side
    study names it), the cores this process may use, torch's threads where torch is loaded,
    OMP_NUM_THREADS and the load average now (other work on a shared machine slows a run)."""
    from ..kernels.runtime import cpu_description
    from ..threads import machine_cores

    cpu, vector = cpu_description()
    torch = sys.modules.get("torch")
    return {"cpu": cpu, "vector": vector, "cores": machine_cores(),
            "torch_threads": torch.get_num_threads() if torch is not None else None,
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}


def provenance(with_machine: bool = False, network: dict[str, Any] | None = None
               ) -> dict[str, Any]:
    """The ``provenance`` entry of a results JSON; ``with_machine`` where it holds times;
    ``network`` the configuration of the network the figures describe where it is not
    today's default (a model trained with other settings), its heads left out as the
    default's are."""
    network = default_network() if network is None else {
        key: value for key, value in network.items() if key != "heads"}
    record = {"commit": commit(), "network_hash": network_hash(network), "network": network,
              "recipe": default_recipe()}
    if with_machine:
        record["machine"] = machine()
    return record


def stamp(data: dict[str, Any], with_machine: bool = False) -> dict[str, Any]:
    """``data`` with its ``provenance`` (a copy; ``data`` is left as it is), which names the
    network its figures describe: a report's model's (``data["config"]["network"]``, as
    ``evaluate`` and the demo write it) where it holds one, else today's default."""
    config = data.get("config")
    network = config.get("network") if isinstance(config, dict) else None
    return {**data, "provenance": provenance(
        with_machine, network if isinstance(network, dict) else None)}
