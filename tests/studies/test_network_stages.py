"""tools/network_stages.py: the arithmetic it reports follows from the network's layers and
the encoder's layout, counted here independently, and a short run gives every stage a time;
absurd sizes end in one error line."""

import json
import pathlib

import pytest
import torch
from tool_errors import load_tool, one_error_line

from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import Heads, NetworkConfig

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "network_stages.py"


def test_the_counts_follow_from_the_layers_and_the_encoders_layout():
    tool = load_tool(TOOL)
    network = IntersectionNetwork(NetworkConfig(heads=Heads(albedo=True)))
    # 84 encoded values, three hidden layers of 64, the heads' columns
    weights = [p for name, p in network.mlp.named_parameters() if name.endswith("weight")]
    assert tool.multiply_adds(network.mlp) == sum(w.shape[0] * w.shape[1] for w in weights)
    assert tool.multiply_adds(torch.nn.Sequential(torch.nn.Linear(3, 5), torch.nn.ReLU(),
                                                  torch.nn.Linear(5, 2))) == 25
    # two end points, x and F sin / cos points each, one lookup per level
    config = network.config
    assert tool.lookups(network.encoder) == 2 * (1 + 2 * config.pe_bands) * config.levels == 28
    assert network.encoder.output_dim == tool.lookups(network.encoder) * config.feature_dim


def test_a_short_run_times_every_stage():
    threads = torch.get_num_threads()
    result = load_tool(TOOL).measure(segments=256, rounds=1)
    assert torch.get_num_threads() == threads            # one thread within, as before after
    assert set(result["ns"]) == {"encoder", "encoder_small_table", "mlp", "mlp_bfloat16",
                                 "readout", "normal_field", "albedo_field"}
    assert all(value > 0 for value in result["ns"].values())
    assert result["encoder_ns_per_lookup"] == pytest.approx(result["ns"]["encoder"] / 28)
    assert result["gemm_gflops"]["float32"] > 0 and result["table_read_share"] < 1
    assert ("bfloat16" in result["gemm_gflops"]) is result["bfloat16_native"]


@pytest.mark.parametrize("native", [True, False])
def test_the_table_says_where_bfloat16_is_emulated(native):
    """Without bfloat16 instructions the product refuses bfloat16: the table says the rate
    is an emulation's, not a share of an emulated product's rate (which took a minute)."""
    tool = load_tool(TOOL)
    result = {"ns": {"encoder": 700.0, "mlp": 500.0, "mlp_bfloat16": 6700.0, "readout": 17.0,
                     "normal_field": 536.0},
              "gemm_gflops": {"float32": 89.0, **({"bfloat16": 0.3} if native else {})},
              "mlp_gflops": {"float32": 55.0, "bfloat16": 4.1},
              "mlp_share_of_gemm": {"float32": 55 / 89,
                                    **({"bfloat16": 4.1 / 0.3} if native else {})},
              "encoder_lookups": 28, "encoder_ns_per_lookup": 25.0,
              "encoder_small_table_ns_per_lookup": 20.0, "table_read_share": 0.2,
              "mlp_multiply_adds": 13696, "field_multiply_adds": {"normal": 768},
              "bfloat16_native": native}
    row = next(line for line in tool.table(result).splitlines() if "MLP, bfloat16" in line)
    assert ("emulated" in row and "%" not in row and "4.1 GFLOP/s" in row) is not native
    assert ("1367 %" in row) is native
    assert "62 % of a 2048x2048 product's 89" in tool.table(result)


def test_absurd_sizes_end_in_one_error_line():
    assert "at least 1" in one_error_line(TOOL, ["--segments", "0"])


def test_a_rerun_replaces_its_own_figures(tmp_path):
    tool = load_tool(TOOL)
    out = tmp_path / "stages.json"
    for _ in range(2):
        tool.main(["--segments", "256", "--rounds", "1", "--json", str(out)])
        record = json.loads(out.read_text())
        assert next(iter(record)) == "format" and record["format"] == tool.FORMAT
        assert record["segments"] == 256 and "provenance" in record
