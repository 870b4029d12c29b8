"""Where the network's time goes on this CPU, stage by stage, against what the machine can do:
the encoder per segment and per hash-grid lookup (at the model's table and at a table small
enough to stay in the L1 cache, which tells the table reads' share from the arithmetic's),
the MLP in float32 and bfloat16 against a large matrix product's rate on the same thread
(the machine's attainable peak for the layers), the readout of the heads' outputs, and the
point fields at the hit.

    .venv/bin/python tools/network_stages.py [--segments 16384] [--rounds 7] [--json PATH]

One torch thread (the product's default); each Warp launch runs on the calling thread, the
encoder's not split (``threads.lane_cores(1, encoder=1)``). The stages alternate within each
round and each figure is the median of the rounds. The network is the default one
(``NetworkConfig()``) with the albedo field of a textured scene; its weights are random,
which changes no stage's cost. ``--json`` writes the figures marked as the tool's, checked by
the output rule before any stage is timed and written atomically: it replaces only a file the
tool wrote.
"""

import argparse
import pathlib
import statistics
import sys
import time

import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon import threads  # noqa: E402
from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.kernels import runtime  # noqa: E402
from vdnif_addon.model.encoding import HashGrid, SegmentEncoder  # noqa: E402
from vdnif_addon.model.network import PREDICT_BATCH, IntersectionNetwork, readout  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402
from vdnif_addon.settings import Heads, NetworkConfig  # noqa: E402

SMALL_TABLE = 8
"""log2 rows of the cache-resident table: 2 levels of 256 rows of 12 bytes, 6 kB."""

GEMM_SIDE = 2048
"""The side of the square matrix product whose rate stands for the thread's peak."""

VOXEL_SIZE = 0.03

FORMAT = "vdnif-network-stages"
"""The figures' format mark: the output rule lets ``--json`` replace only the tool's own file."""


def multiply_adds(mlp: torch.nn.Module) -> int:
    """Multiply-adds per row of an MLP: every linear layer's inputs times outputs."""
    return sum(layer.in_features * layer.out_features for layer in mlp.modules()
               if isinstance(layer, torch.nn.Linear))


def lookups(encoder: SegmentEncoder) -> int:
    """Hash-grid lookups (8 corner reads each) per segment: two end points, 1 + 2F gamma
    points each, one lookup per level."""
    return 2 * (1 + 2 * encoder.pe_bands) * encoder.grid.levels


def measure(segments: int = PREDICT_BATCH["cpu"], rounds: int = 7, seed: int = 0) -> dict:
    """Every stage's median seconds over ``rounds`` alternating rounds, per segment (or per
    point, for the fields) in nanoseconds, with the arithmetic that bounds it."""
    if segments < 1 or rounds < 1:
        raise VDNIFError(f"segments and rounds must be at least 1, got {segments} and {rounds}")
    runtime.load_all(runtime.device(torch.device("cpu")))
    generator = torch.Generator().manual_seed(seed)
    config = NetworkConfig(heads=Heads(albedo=True))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        network = IntersectionNetwork(config).eval()
        small = SegmentEncoder(HashGrid(config.levels, config.base_resolution, config.growth,
                                        SMALL_TABLE, config.feature_dim), config.pe_bands,
                               config.pe_form)
    p0, p1, points = (torch.rand(segments, 3, generator=generator) for _ in range(3))
    rest = torch.rand(segments, generator=generator) * VOXEL_SIZE
    a, b = (torch.rand(GEMM_SIDE, GEMM_SIDE, generator=generator) for _ in range(2))
    with torch.inference_mode():
        features = network.encoder(p0, p1)
        outputs = network.heads(features)

        def bf16(run):
            def within():
                with torch.autocast("cpu", dtype=torch.bfloat16):
                    return run()
            return within

        stages = {
            "encoder": lambda: network.encoder(p0, p1),
            "encoder_small_table": lambda: small(p0, p1),
            "mlp": lambda: network.mlp(features),
            "mlp_bfloat16": bf16(lambda: network.mlp(features)),
            "readout": lambda: readout(outputs, config.distance_mode, VOXEL_SIZE, rest),
            "gemm": lambda: a @ b,
        }
        native = runtime.bfloat16_native(torch.device("cpu"))
        if native:      # emulated, the large product takes about a minute and bounds nothing
            stages["gemm_bfloat16"] = bf16(lambda: a @ b)
        for name, field in network.point_fields().items():
            stages[f"{name}_field"] = lambda field=field: field(points)
        times = {name: [] for name in stages}
        with threads.lane_cores(1, encoder=1), threads.torch_threads_at_most(1):
            for run in stages.values():
                run()                                       # warm-up
            for _ in range(rounds):
                for name, run in stages.items():
                    started = time.perf_counter()
                    run()
                    times[name].append(time.perf_counter() - started)
    seconds = {name: statistics.median(values) for name, values in times.items()}
    per = {name: seconds[name] / segments * 1e9 for name in stages
           if not name.startswith("gemm")}
    peak = {precision: 2 * GEMM_SIDE**3 / seconds[key] / 1e9
            for precision, key in (("float32", "gemm"), ("bfloat16", "gemm_bfloat16"))
            if key in seconds}
    macs = multiply_adds(network.mlp)
    reached = {precision: 2 * macs / (per[key] * 1e-9) / 1e9
               for precision, key in (("float32", "mlp"), ("bfloat16", "mlp_bfloat16"))}
    count = lookups(network.encoder)
    return {
        "what": "the network's stages on one CPU thread, ns per segment (fields: per point)",
        "command": ["python", "tools/network_stages.py", "--segments", str(segments),
                    "--rounds", str(rounds)],
        "segments": segments, "rounds": rounds, "config": config.to_dict(),
        "ns": per,
        "encoder_lookups": count,
        "encoder_ns_per_lookup": per["encoder"] / count,
        "encoder_small_table_ns_per_lookup": per["encoder_small_table"] / count,
        "table_read_share": 1 - per["encoder_small_table"] / per["encoder"],
        "mlp_multiply_adds": macs,
        "gemm_gflops": peak,
        "mlp_gflops": reached,
        "mlp_share_of_gemm": {p: reached[p] / peak[p] for p in peak},
        "bfloat16_native": native,
        "field_multiply_adds": {name: multiply_adds(field.mlp)
                                for name, field in network.point_fields().items()},
    }


def table(result: dict) -> str:
    ns, peak, reached = result["ns"], result["gemm_gflops"], result["mlp_gflops"]
    lines = ["| stage | ns per segment | bound |", "| --- | --- | --- |",
             f"| encoder ({result['encoder_lookups']} lookups of 8 corners) | "
             f"{ns['encoder']:.0f} | {result['encoder_ns_per_lookup']:.1f} ns a lookup; "
             f"{result['encoder_small_table_ns_per_lookup']:.1f} with a 6 kB table, so table "
             f"reads are {100 * result['table_read_share']:.0f} % of it |"]
    for precision, key in (("float32", "mlp"), ("bfloat16", "mlp_bfloat16")):
        if precision == "bfloat16" and not result["bfloat16_native"]:
            bound = (f"{reached[precision]:.1f} GFLOP/s, emulated: this CPU has no bfloat16 "
                     "instructions, and the product refuses bfloat16 here")
        else:
            bound = (f"{reached[precision]:.0f} GFLOP/s, "
                     f"{100 * result['mlp_share_of_gemm'][precision]:.0f} % of a "
                     f"{GEMM_SIDE}x{GEMM_SIDE} product's {peak[precision]:.0f}")
        lines.append(f"| MLP, {precision} ({result['mlp_multiply_adds']:,} multiply-adds) | "
                     f"{ns[key]:.0f} | {bound} |")
    lines.append(f"| readout of the heads | {ns['readout']:.0f} | elementwise passes |")
    for name, macs in result["field_multiply_adds"].items():
        lines.append(f"| {name} field, per point ({macs:,} multiply-adds) | "
                     f"{ns[f'{name}_field']:.0f} | its grid and MLP |")
    return "\n".join(lines)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--segments", type=int, default=PREDICT_BATCH["cpu"],
                        help="segments per stage call (predict's batch by default)")
    parser.add_argument("--rounds", type=int, default=7, help="alternating rounds; medians")
    parser.add_argument("--json", type=pathlib.Path, help="write the figures here")
    args = parser.parse_args(argv)
    if args.json:
        check_output_file(args.json, "--json", "json")     # the output rule, before the timing
    result = measure(args.segments, args.rounds)
    print(table(result))
    if args.json:
        write_json_atomic(args.json, stamp({"format": FORMAT, **result}, with_machine=True),
                          "--json", indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="network_stages: error: ")
