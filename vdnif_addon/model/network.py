"""The intersection network: segment encoder + ReLU MLP + one linear layer split into heads.

DESIGN.md section 8. ``IntersectionNetwork.forward`` returns the head outputs the losses
consume; ``readout`` turns them into predictions in rest-space units.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

from .. import threads
from ..errors import VDNIFError
from ..kernels import runtime
from ..settings import PRECISIONS, NetworkConfig
from .activation import ReLU
from .encoding import HashGrid, SegmentEncoder, scene_log2_table_size
from .metadata import Thresholds

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int64

PREDICT_BATCH = {"cpu": 1 << 14, "cuda": 1 << 20}
"""Segments ``predict`` evaluates at a time, by device type (the CPU's for any other): a
bound on its memory, which grows by about 850 bytes a segment with the default network (its
features and activations in float32, measured on the CPU at 2^20). On the CPU, 2^14 keep a
batch's activations in the cache and let the next batch's encoder run beside this one's MLP.
On CUDA a batch costs a dozen launches or more whatever its size, so a render's wave goes to
the network whole up to 2^20 segments (under 1 GB; a 1920x1080 frame's first wave in 2)."""


def hash_grid(config: NetworkConfig, levels: int | None = None,
              log2_table_size: int | None = None) -> HashGrid:
    """A hash grid of ``config``'s grid settings (the encoder's and the albedo field's), or
    of its base resolution, growth and features with other ``levels`` and
    ``log2_table_size`` (the normal field's)."""
    return HashGrid(config.levels if levels is None else levels, config.base_resolution,
                    config.growth,
                    config.log2_table_size if log2_table_size is None else log2_table_size,
                    config.feature_dim)


def sized_to_scene(config: NetworkConfig, occupied_voxels: int, voxels_across: int
                   ) -> NetworkConfig:
    """``config`` with each grid's table (the encoder's and the albedo field's, the normal
    field's) no larger than its finest level can use on a scene of ``occupied_voxels``
    voxels, its grid ``voxels_across`` voxels across (``encoding.scene_log2_table_size``): a
    thin or small object's model carries no rows it never reads. The table sizes are at most
    the config's."""
    def sized(levels: int, log2_table_size: int) -> int:
        return scene_log2_table_size(log2_table_size, levels, config.base_resolution,
                                     config.growth, occupied_voxels, voxels_across)

    return dataclasses.replace(
        config, log2_table_size=sized(config.levels, config.log2_table_size),
        normal_log2_table_size=sized(config.normal_levels, config.normal_log2_table_size))


class IntersectionNetwork(nn.Module):
    """(p0, p1) rest-space segments -> per-head outputs.

    Encoder ``psi`` of both end points, ``depth`` hidden ReLU layers of ``width``, one linear
    output layer whose columns are split into the heads of ``config.heads``.
    """

    def __init__(self, config: NetworkConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = SegmentEncoder(hash_grid(config), config.pe_bands, config.pe_form)
        # The tasks (the losses' and the weighting's), and the MLP's output columns: the
        # same heads, less those that a field of the rest point gives at the hit.
        self.head_sizes = config.heads.sizes()
        self.albedo_field = (PointField(hash_grid(config), config.width, hidden=2)
                             if "albedo" in self.head_sizes and config.albedo_mode == "hit"
                             else None)
        # One hidden layer: the table holds the normal (two were no better on the bunny's
        # held-out hits), and the render reads the field at every hit.
        self.normal_field = (PointField(hash_grid(config, config.normal_levels,
                                                  config.normal_log2_table_size),
                                        config.width, hidden=1)
                             if config.normal_mode == "hit" else None)
        self.mlp_heads = {name: size for name, size in self.head_sizes.items()
                          if name not in self.point_fields()}
        layers: list[nn.Module] = []
        width_in = self.encoder.output_dim
        for _ in range(config.depth):
            # In place: nothing reads a layer's output but its ReLU, and a second tensor of a
            # batch's activations, written to fresh pages, costs as much as the ReLU itself.
            layers += [nn.Linear(width_in, config.width), ReLU()]
            width_in = config.width
        output = nn.Linear(width_in, sum(self.mlp_heads.values()))
        if config.distance_mode != "fraction":
            # ReLU output: start it in its active range (log1p of one half), or a
            # head whose first outputs are all negative never gets a gradient (a dead ReLU).
            distance_column = list(self.mlp_heads).index("distance")
            start = sum(list(self.mlp_heads.values())[:distance_column])
            with torch.no_grad():
                output.bias[start] = math.log1p(0.5)
        layers.append(output)
        self.mlp = nn.Sequential(*layers)
        # Not parameters: training calibrates them on held-out poses (``validation``), the
        # model file's metadata carries them and ``load_model`` hands them over; ``predict``
        # applies them.
        self.thresholds = Thresholds()
        # Not saved either: how ``predict`` runs the MLPs, "float32" or "bfloat16". A render
        # sets it from its setting (``resolve_precision``); training and its
        # calibration keep float32.
        self.precision = "float32"

    def forward(
        self, p0: Float[torch.Tensor, "batch 3"], p1: Float[torch.Tensor, "batch 3"],
        hit_frac: Float[torch.Tensor, " batch"] | None = None,
        rows: Int64[torch.Tensor, " rows"] | None = None,
    ) -> dict[str, Float[torch.Tensor, "batch ..."]]:
        """p0, p1: (N, 3) normalized rest coordinates in [0,1] -> head outputs.

        ``occlusion`` (N,) logit; ``distance`` (N,) sigmoid fraction t/l, ReLU log1p(t/l)
        or ReLU log1p(d/h) per ``distance_mode``; ``normal`` (N, 3) unnormalized; ``albedo``
        (N, 3) in [0,1]; ``material`` (N, M) logits. Only the heads of ``config.heads`` are
        present. A head that a field gives (``point_fields``) is the field's at
        ``p0 + hit_frac (p1 - p0)``, the reference's hit (N,) t/l, on the row indices
        ``rows`` (every row without them; 0 on the others, where no loss reads it), and
        absent without ``hit_frac``.
        """
        outputs = self.heads(self.encoder(p0, p1))
        if hit_frac is not None:
            self.add_fields(outputs, p0, p1, hit_frac, rows)
        return outputs

    def add_fields(
        self, outputs: dict[str, Float[torch.Tensor, "batch ..."]],
        p0: Float[torch.Tensor, "batch 3"], p1: Float[torch.Tensor, "batch 3"],
        hit_frac: Float[torch.Tensor, " batch"],
        rows: Int64[torch.Tensor, " rows"] | None = None,
    ) -> None:
        """Adds to the head ``outputs`` of segments p0, p1 the heads that a field gives, at
        the reference's hit ``hit_frac`` on the rows ``rows`` (``forward`` says how)."""
        fields = self.point_fields()
        if fields and rows is None:
            rows = torch.arange(len(p0), device=p0.device)
        if fields:
            point = p0[rows] + hit_frac[rows].unsqueeze(1) * (p1[rows] - p0[rows])
        for name in fields:
            value = self.field_at(name, point)
            outputs[name] = value.new_zeros(len(p0), value.shape[1]).index_copy(0, rows, value)

    def point_fields(self) -> dict[str, PointField]:
        """Heads that a field of the rest point gives at the hit (``albedo_mode``,
        ``normal_mode`` "hit"), in head order."""
        return {name: field for name, field in (("normal", self.normal_field),
                                                ("albedo", self.albedo_field))
                if field is not None}

    def field_at(self, name: str, points: Float[torch.Tensor, "batch 3"]
                 ) -> Float[torch.Tensor, "batch 3"]:
        """Head ``name``'s field at normalized rest points (N, 3): the albedo in [0,1], the
        normal unnormalized (as the MLP's heads give them)."""
        value = self.point_fields()[name](points)
        return torch.sigmoid(value) if name == "albedo" else value

    def heads(
        self, features: Float[torch.Tensor, "batch features"]
    ) -> dict[str, Float[torch.Tensor, "batch ..."]]:
        """Head outputs (see ``forward``) of encoded segments, features (N, encoder.output_dim)."""
        # float32 from here: under bfloat16 autocast only the MLP's layers are bfloat16
        columns = self.mlp(features).float().split(list(self.mlp_heads.values()), dim=1)
        raw = dict(zip(self.mlp_heads, columns))
        distance_activation = torch.sigmoid if self.config.distance_mode == "fraction" else F.relu
        out = {
            "occlusion": raw["occlusion"].squeeze(1),
            "distance": distance_activation(raw["distance"].squeeze(1)),
        }
        if "normal" in raw:
            out["normal"] = raw["normal"]
        if "albedo" in raw:
            out["albedo"] = torch.sigmoid(raw["albedo"])
        if "material" in raw:
            out["material"] = raw["material"]
        return out

    @torch.inference_mode()
    def predict(
        self,
        p0: Float[torch.Tensor, "batch 3"],
        p1: Float[torch.Tensor, "batch 3"],
        rest_len: Float[torch.Tensor, " batch"],
        voxel_size: float,
        batch: int | None = None,
        select_candidates: bool = True,
    ) -> dict[str, Float[torch.Tensor, "batch ..."] | Bool[torch.Tensor, " batch"]
              | Int64[torch.Tensor, " batch"]]:
        """Predictions for segments p0, p1 (N, 3) with rest lengths (N,): ``readout`` of
        ``forward`` at the model's ``thresholds``, its MLPs in its ``precision``, without
        autograd, ``batch`` segments at a time to bound memory (by default the device's
        ``PREDICT_BATCH``). The point fields
        (``point_fields``) are read at each candidate segment's predicted hit,
        ``p0 + fraction (p1 - p0)`` (their heads are 0 on the other segments), once every
        batch has its predictions; a field's normal is made unit as the head's is. Finding
        the candidates reads the device on the host; with ``select_candidates`` False the
        fields are evaluated at every segment instead and kept at the candidates, no read.

        On the CPU the encoder of batch k+1 runs beside the MLP of batch k (``encoded``).
        """
        batch = batch or PREDICT_BATCH.get(p0.device.type, PREDICT_BATCH["cpu"])
        chunks = list(zip(p0.split(batch), p1.split(batch), rest_len.split(batch)))
        if not chunks:
            chunks = [(p0, p1, rest_len)]
        mode = self.config.distance_mode

        def predictions(index: int, features: Float[torch.Tensor, "chunk features"]
                        ) -> dict[str, torch.Tensor]:
            with self.mlp_arithmetic(features.device):
                outputs = self.heads(features)
            return readout(outputs, mode, voxel_size, chunks[index][2], self.thresholds)

        parts = [predictions(index, features) for index, features in
                 enumerate(self.encoded([(p0, p1) for p0, p1, _ in chunks]))]
        result = {key: torch.cat([part[key] for part in parts]) for key in parts[0]}
        fields = self.point_fields()
        if fields and not select_candidates:
            candidate = result["candidate"].unsqueeze(1)
            fraction = result["fraction"].to(p0.dtype).unsqueeze(1)
            for name in fields:
                parts = []
                for start in range(0, len(p0), batch):
                    rows = slice(start, start + batch)
                    point = p0[rows] + fraction[rows] * (p1[rows] - p0[rows])
                    with self.mlp_arithmetic(point.device):
                        value = self.field_at(name, point)
                    if name == "normal":
                        value = F.normalize(value.float(), dim=1)
                    parts.append(torch.where(candidate[rows], value.to(p0.dtype), 0))
                result[name] = torch.cat(parts) if parts else p0.new_zeros(0, 3)
        elif fields:
            # Only candidates can place a hit (hits are candidates too): most segments are
            # not, and skip the fields. They are found once, over every batch: finding them
            # reads the device on the host, and on CUDA that waits for all work queued.
            chosen = result["candidate"].nonzero().squeeze(1)
            answers = {name: p0.new_zeros(len(p0), 3) for name in fields}
            for rows in chosen.split(batch):
                point = p0[rows] + result["fraction"][rows].to(p0.dtype).unsqueeze(1) * (
                    p1[rows] - p0[rows])
                for name, answer in answers.items():
                    with self.mlp_arithmetic(point.device):
                        value = self.field_at(name, point)
                    if name == "normal":
                        value = F.normalize(value.float(), dim=1)
                    # index_copy does not promote on CUDA as it does on the CPU: a field
                    # that answers in another dtype is cast to the destination's.
                    answer.index_copy_(0, rows, value.to(answer.dtype))
            result.update(answers)
        return result

    def encoded(self, pairs: Sequence[tuple[Float[torch.Tensor, "chunk 3"],
                                            Float[torch.Tensor, "chunk 3"]]]
                ) -> Iterator[Float[torch.Tensor, "chunk features"]]:
        """The encoder's features of each (p0, p1) of ``pairs`` in turn, without autograd,
        in the dtype the first layer reads under ``mlp_arithmetic``.

        On the CPU with more than one core (``threads.cores()``) the encoder of pair k+1
        runs in a worker thread (one core: a Warp CPU launch is serial and releases the GIL),
        on the cores torch's threads leave, while the caller runs the MLP of pair k (torch's
        threads); the caller launches no kernel meanwhile. A launch's features are the same
        on any number of cores."""

        def encode(index: int) -> Float[torch.Tensor, "chunk features"]:
            # inference mode and autocast are per thread
            p0, p1 = pairs[index]
            with torch.inference_mode(), self.mlp_arithmetic(p0.device):
                return self.encoder(p0, p1)

        if not pairs or pairs[0][0].device.type != "cpu" or len(pairs) == 1 \
                or threads.cores() == 1:
            # CUDA launches are asynchronous already: the stream overlaps them with the host;
            # one core has nothing to run the encoder beside the MLP on.
            for index in range(len(pairs)):
                yield encode(index)
            return
        # Beside the MLP the encoder keeps to the cores torch's threads leave: split over
        # every core, it would take one from the MLP.
        cores = threads.cores()
        spare = max(1, cores - torch.get_num_threads())

        def encode_beside(index: int) -> Float[torch.Tensor, "chunk features"]:
            with threads.lane_cores(cores, spare):
                return encode(index)

        with ThreadPoolExecutor(1, thread_name_prefix="vdnif-encoder") as worker:
            pending = worker.submit(encode, 0)
            for index in range(len(pairs)):
                features = pending.result()
                if index + 1 < len(pairs):
                    pending = worker.submit(encode_beside, index + 1)
                yield features

    def mlp_arithmetic(self, device: torch.device) -> torch.autocast:
        """The MLPs' arithmetic in ``predict``: bfloat16 where ``precision`` says so (the
        hash grids look up in float32 under autocast and hand their features on rounded to
        bfloat16, as the first layer reads them: ``encoding.feature_dtype``)."""
        return torch.autocast(device.type, dtype=torch.bfloat16,
                              enabled=self.precision == "bfloat16")


class PointField(nn.Module):
    """A head's value at a normalized rest-space point (N, 3) -> (N, 3): a hash ``grid`` and
    a ReLU MLP of ``width`` with ``hidden`` layers (the albedo field that
    ``tools/albedo_ceiling.py`` measures against the model's albedo head). A
    point decides the albedo and the normal of the surface through it; the MLP's heads read
    them from the segment's two end points, so theirs do not follow where the hit is placed."""

    def __init__(self, grid: HashGrid, width: int, hidden: int) -> None:
        super().__init__()
        self.grid = grid
        layers: list[nn.Module] = []
        width_in = self.grid.output_dim
        for _ in range(hidden):
            layers += [nn.Linear(width_in, width), ReLU()]  # in place, as the trunk's
            width_in = width
        self.mlp = nn.Sequential(*layers, nn.Linear(width_in, 3))

    def forward(self, points: Float[torch.Tensor, "batch 3"]) -> Float[torch.Tensor, "batch 3"]:
        return self.mlp(self.grid(points)).float()


def resolve_precision(precision: str, device: torch.device) -> str:
    """The MLPs' arithmetic, "float32" or "bfloat16", that ``precision``
    (``settings.PRECISIONS``) asks of ``device``: auto is bfloat16 where the device has
    bfloat16 instructions and float32 elsewhere; bfloat16 on a device without them raises a
    one-line VDNIFError (torch would emulate it, slower than float32)."""
    if precision not in PRECISIONS:
        raise VDNIFError(f"precision '{precision}': choose one of {', '.join(PRECISIONS)}")
    if precision == "auto":
        return "bfloat16" if runtime.bfloat16_native(device) else "float32"
    if precision == "bfloat16" and not runtime.bfloat16_native(device):
        raise VDNIFError(f"precision bfloat16: {device} has no bfloat16 instructions "
                         "(CUDA, or a CPU with AVX-512 BF16 or AMX): it would run slower "
                         "than float32")
    return precision


def readout(
    outputs: Mapping[str, Float[torch.Tensor, "batch ..."]],
    distance_mode: str,
    voxel_size: float,
    rest_len: Float[torch.Tensor, " batch"],
    thresholds: Thresholds = Thresholds(),
) -> dict[str, Float[torch.Tensor, "batch ..."] | Bool[torch.Tensor, " batch"]
          | Int64[torch.Tensor, " batch"]]:
    """Head outputs -> predictions.

    rest_len: (N,) rest-space segment length |p1 - p0|; voxel_size: h in rest units.
    Returns ``hit_probability`` (N,), ``hit`` (N,) bool (probability above the occlusion
    threshold of ``thresholds``, the model's calibrated ones), ``candidate`` (N,) bool
    (probability above their candidate threshold),
    ``distance`` (N,) rest-space local distance d from p0, ``fraction`` (N,) d / rest_len in
    [0,1] (the renderer's t = fraction * l),
    ``normal`` (N, 3) unit (zero where the head output is zero), ``material`` (N,) int64
    (0 without a material head) and, with an albedo head, ``albedo`` (N, 3); the normal
    and the albedo only where ``outputs`` has them (not where a point field gives them).
    """
    if not (isinstance(voxel_size, numbers.Real) and math.isfinite(voxel_size) and voxel_size > 0):
        raise VDNIFError(f"voxel size must be a positive number, got {voxel_size!r}")
    probability = torch.sigmoid(outputs["occlusion"])
    if distance_mode == "fraction":
        fraction = outputs["distance"]
    elif distance_mode == "log-distance":
        # d = h expm1(y) from the segment's start; the hit stays in its segment.
        local = voxel_size * torch.expm1(outputs["distance"].clamp(max=20.0))
        fraction = torch.where(rest_len > 0, local / rest_len.clamp_min(1e-30),
                               0.0).clamp(0.0, 1.0)
    else:
        fraction = torch.expm1(outputs["distance"]).clamp(0.0, 1.0)
    distance = fraction * rest_len
    predictions = {
        "hit_probability": probability,
        "hit": probability > thresholds.occlusion,
        "candidate": probability > thresholds.candidate,
        "distance": distance,
        "fraction": fraction,
        "material": outputs["material"].argmax(1)
        if "material" in outputs
        else torch.zeros_like(probability, dtype=torch.int64),
    }
    if "normal" in outputs:
        predictions["normal"] = F.normalize(outputs["normal"], dim=1)
    if "albedo" in outputs:
        predictions["albedo"] = outputs["albedo"]
    return predictions
