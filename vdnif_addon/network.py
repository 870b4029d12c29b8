"""The intersection network: segment encoder + ReLU MLP + one linear layer split into heads.

DESIGN.md section 8. ``IntersectionNetwork.forward`` returns the head outputs the losses
consume; ``readout`` turns them into predictions in rest-space units.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .encoding import (
    HashGrid,
    SegmentEncoder,
    check_encoding_settings,
    check_grid_settings,
    check_int,
)
from .errors import VDNIFError
from .settings import OCCLUSION_THRESHOLD

DISTANCE_MODES = ("fraction", "log1p")
"""``fraction``: LSNIF's sigmoid t/l. ``log1p``: the scale-invariant ReLU log1p(d/h)."""


@dataclass(frozen=True)
class Heads:
    """Which outputs the scene needs (DESIGN.md section 7).

    Occlusion, distance and normal are always present; albedo only when it is not constant
    per material (else a lookup table replaces it); material only when there are several.
    """

    albedo: bool = True
    material_count: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.albedo, bool):
            raise VDNIFError(f"heads setting albedo must be true or false, got {self.albedo!r}")
        check_int("material_count", self.material_count, 1, 2**15)

    @property
    def material(self) -> bool:
        return self.material_count > 1

    def sizes(self) -> dict[str, int]:
        """Head name -> output width, in output-column order."""
        sizes = {"occlusion": 1, "distance": 1, "normal": 3}
        if self.albedo:
            sizes["albedo"] = 3
        if self.material:
            sizes["material"] = self.material_count
        return sizes

    @classmethod
    def from_header(cls, heads: Mapping[str, Any]) -> Heads:
        """From a dataset header's ``heads`` entry: {"albedo": bool, "material_count": int, ...}."""
        if not isinstance(heads, Mapping) or not {"albedo", "material_count"} <= set(heads):
            raise VDNIFError(
                f"dataset header 'heads' must give 'albedo' and 'material_count', got {heads!r}"
            )
        return cls(albedo=heads["albedo"], material_count=heads["material_count"])


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture of one intersection network; defaults are the paper's setting."""

    levels: int = 2
    base_resolution: int = 64
    growth: float = 2.0
    log2_table_size: int = 16
    feature_dim: int = 3
    pe_bands: int = 3
    pe_form: str = "paper"
    width: int = 64
    depth: int = 3
    distance_mode: str = "log1p"
    heads: Heads = field(default_factory=Heads)

    def __post_init__(self) -> None:
        check_grid_settings(
            self.levels, self.base_resolution, self.growth, self.log2_table_size, self.feature_dim
        )
        check_encoding_settings(self.pe_bands, self.pe_form)
        check_int("width", self.width, 1, 4096)
        check_int("depth", self.depth, 1, 64)
        if self.distance_mode not in DISTANCE_MODES:
            modes = list(DISTANCE_MODES)
            raise VDNIFError(
                f"setting distance_mode must be one of {modes}, got {self.distance_mode!r}"
            )
        if not isinstance(self.heads, Heads):
            raise VDNIFError(f"setting heads must be a Heads, got {self.heads!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> NetworkConfig:
        """Inverse of ``to_dict``; unknown or malformed entries raise VDNIFError."""
        if not isinstance(data, Mapping):
            raise VDNIFError(f"network config must be a mapping, got {type(data).__name__}")
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise VDNIFError(f"network config has unknown entries {sorted(unknown)}")
        values = dict(data)
        if "heads" in values:
            heads = values["heads"]
            if not isinstance(heads, Mapping) or not set(heads) <= {"albedo", "material_count"}:
                raise VDNIFError(f"network config has malformed heads: {heads!r}")
            values["heads"] = Heads(**heads)
        return cls(**values)


class IntersectionNetwork(nn.Module):
    """(p0, p1) rest-space segments -> per-head outputs.

    Encoder ``psi`` of both end points, ``depth`` hidden ReLU layers of ``width``, one linear
    output layer whose columns are split into the heads of ``config.heads``.
    """

    def __init__(self, config: NetworkConfig) -> None:
        super().__init__()
        self.config = config
        grid = HashGrid(
            config.levels,
            config.base_resolution,
            config.growth,
            config.log2_table_size,
            config.feature_dim,
        )
        self.encoder = SegmentEncoder(grid, config.pe_bands, config.pe_form)
        self.head_sizes = config.heads.sizes()
        layers: list[nn.Module] = []
        width_in = self.encoder.output_dim
        for _ in range(config.depth):
            layers += [nn.Linear(width_in, config.width), nn.ReLU()]
            width_in = config.width
        output = nn.Linear(width_in, sum(self.head_sizes.values()))
        if config.distance_mode == "log1p":
            # ReLU output: start it in its active range (log1p of half a voxel), or a head
            # whose first outputs are all negative never gets a gradient (a dead ReLU).
            distance_column = list(self.head_sizes).index("distance")
            start = sum(list(self.head_sizes.values())[:distance_column])
            with torch.no_grad():
                output.bias[start] = math.log1p(0.5)
        layers.append(output)
        self.mlp = nn.Sequential(*layers)
        # Not a parameter: training calibrates it on held-out poses (``train.calibrate_
        # threshold``) and the model file stores it; ``predict`` applies it.
        self.occlusion_threshold = OCCLUSION_THRESHOLD

    def forward(self, p0: torch.Tensor, p1: torch.Tensor) -> dict[str, torch.Tensor]:
        """p0, p1: (N, 3) normalized rest coordinates in [0,1] -> head outputs.

        ``occlusion`` (N,) logit; ``distance`` (N,) sigmoid fraction t/l or ReLU log1p(d/h)
        per ``distance_mode``; ``normal`` (N, 3) unnormalized; ``albedo`` (N, 3) in [0,1];
        ``material`` (N, M) logits. Only the heads of ``config.heads`` are present.
        """
        return self.heads(self.encoder(p0, p1))

    def heads(self, features: torch.Tensor) -> dict[str, torch.Tensor]:
        """Head outputs (see ``forward``) of encoded segments, features (N, encoder.output_dim)."""
        columns = self.mlp(features).split(list(self.head_sizes.values()), dim=1)
        raw = dict(zip(self.head_sizes, columns))
        distance_activation = torch.sigmoid if self.config.distance_mode == "fraction" else F.relu
        out = {
            "occlusion": raw["occlusion"].squeeze(1),
            "distance": distance_activation(raw["distance"].squeeze(1)),
            "normal": raw["normal"],
        }
        if "albedo" in raw:
            out["albedo"] = torch.sigmoid(raw["albedo"])
        if "material" in raw:
            out["material"] = raw["material"]
        return out

    @torch.inference_mode()
    def predict(
        self,
        p0: torch.Tensor,
        p1: torch.Tensor,
        rest_len: torch.Tensor,
        voxel_size: float,
        batch: int = 2**14,
    ) -> dict[str, torch.Tensor]:
        """Predictions for segments p0, p1 (N, 3) with rest lengths (N,): ``readout`` of
        ``forward`` at the model's ``occlusion_threshold``, without autograd, ``batch``
        segments at a time to bound memory.

        On the CPU the encoder of batch k+1 runs in a worker thread (one core: a Warp CPU
        launch is serial and releases the GIL) while this thread runs the MLP of batch k
        (torch's threads); only the worker launches kernels meanwhile.
        """
        chunks = list(zip(p0.split(batch), p1.split(batch), rest_len.split(batch)))
        if not chunks:
            chunks = [(p0, p1, rest_len)]
        mode = self.config.distance_mode

        def encode(index: int) -> torch.Tensor:
            with torch.inference_mode():  # inference mode is per thread
                return self.encoder(chunks[index][0], chunks[index][1])

        parts = []
        if p0.device.type != "cpu" or len(chunks) == 1:
            # CUDA launches are asynchronous already: the stream overlaps them with the host.
            for index, (_, _, length) in enumerate(chunks):
                parts.append(readout(self.heads(encode(index)), mode, voxel_size, length,
                                     self.occlusion_threshold))
        else:
            with ThreadPoolExecutor(1, thread_name_prefix="vdnif-encoder") as worker:
                pending = worker.submit(encode, 0)
                for index, (_, _, length) in enumerate(chunks):
                    features = pending.result()
                    if index + 1 < len(chunks):
                        pending = worker.submit(encode, index + 1)
                    parts.append(readout(self.heads(features), mode, voxel_size, length,
                                         self.occlusion_threshold))
        return {key: torch.cat([part[key] for part in parts]) for key in parts[0]}


def readout(
    outputs: Mapping[str, torch.Tensor],
    distance_mode: str,
    voxel_size: float,
    rest_len: torch.Tensor,
    threshold: float = OCCLUSION_THRESHOLD,
) -> dict[str, torch.Tensor]:
    """Head outputs -> predictions.

    rest_len: (N,) rest-space segment length |p1 - p0|; voxel_size: h in rest units.
    Returns ``hit_probability`` (N,), ``hit`` (N,) bool (probability above ``threshold``,
    the model's calibrated occlusion threshold), ``distance`` (N,) rest-space local
    distance d from p0, ``fraction`` (N,) d / rest_len in [0,1] (the renderer's t = fraction * l),
    ``normal`` (N, 3) unit (zero where the head output is zero), ``material`` (N,) int64
    (0 without a material head) and, with an albedo head, ``albedo`` (N, 3).
    """
    if not (isinstance(voxel_size, numbers.Real) and math.isfinite(voxel_size) and voxel_size > 0):
        raise VDNIFError(f"voxel size must be a positive number, got {voxel_size!r}")
    probability = torch.sigmoid(outputs["occlusion"])
    if distance_mode == "fraction":
        fraction = outputs["distance"]
        distance = fraction * rest_len
    else:
        distance = voxel_size * torch.expm1(outputs["distance"])
        fraction = (distance / rest_len.clamp_min(torch.finfo(distance.dtype).tiny)).clamp(0.0, 1.0)
    predictions = {
        "hit_probability": probability,
        "hit": probability > threshold,
        "distance": distance,
        "fraction": fraction,
        "normal": F.normalize(outputs["normal"], dim=1),
        "material": outputs["material"].argmax(1)
        if "material" in outputs
        else torch.zeros_like(probability, dtype=torch.int64),
    }
    if "albedo" in outputs:
        predictions["albedo"] = outputs["albedo"]
    return predictions
