import copy
import math

import pytest
import torch
from host_reads import counting_host_reads

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model.activation import ReLU
from vdnif_addon.model.metadata import Thresholds
from vdnif_addon.model.network import IntersectionNetwork, readout
from vdnif_addon.settings import DISTANCE_MODES, Heads, NetworkConfig

# The paper's albedo and normal heads over the segment; the point fields have tests of their
# own.
SMALL = {"levels": 2, "base_resolution": 8, "log2_table_size": 10, "width": 16, "depth": 2,
         "albedo_mode": "segment", "normal_mode": "segment"}


@pytest.mark.parametrize(
    "heads, expected",
    [
        (Heads(), {"occlusion": 1, "distance": 1, "normal": 3, "albedo": 3}),
        (Heads(albedo=False, material_count=1), {"occlusion": 1, "distance": 1, "normal": 3}),
        (
            Heads(albedo=True, material_count=5),
            {"occlusion": 1, "distance": 1, "normal": 3, "albedo": 3, "material": 5},
        ),
        (
            Heads(albedo=False, material_count=2),
            {"occlusion": 1, "distance": 1, "normal": 3, "material": 2},
        ),
    ],
)
def test_heads_present_only_when_the_scene_needs_them(heads, expected):
    assert heads.sizes() == expected
    network = IntersectionNetwork(NetworkConfig(**SMALL, heads=heads))
    outputs = network(*torch.rand(2, 13, 3))
    assert {key: value.shape for key, value in outputs.items()} == {
        key: (13,) if width == 1 else (13, width) for key, width in expected.items()
    }
    assert network.mlp[-1].out_features == sum(expected.values())


def test_paper_architecture():
    network = IntersectionNetwork(NetworkConfig(albedo_mode="segment", normal_mode="segment"))
    linears = [layer for layer in network.mlp if isinstance(layer, torch.nn.Linear)]
    assert [(layer.in_features, layer.out_features) for layer in linears] == [
        (84, 64),
        (64, 64),
        (64, 64),
        (64, 8),
    ]
    assert sum(isinstance(layer, ReLU) for layer in network.mlp) == 3


@pytest.mark.parametrize("mode", DISTANCE_MODES)
def test_distance_activation(mode):
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(**SMALL, distance_mode=mode))
    with torch.no_grad():
        network.mlp[-1].bias[1] = -5.0  # push the distance pre-activation negative
    distance = network(*torch.rand(2, 50, 3))["distance"]
    if mode == "fraction":
        assert ((distance > 0) & (distance < 1)).all()
    else:
        assert (distance == 0).all()


def test_readout_fraction_mode():
    outputs = {
        "occlusion": torch.tensor([2.0, -1.0]),
        "distance": torch.tensor([0.25, 1.0]),
        "normal": torch.tensor([[0.0, 3.0, 4.0], [0.0, 0.0, 0.0]]),
        "albedo": torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]),
        "material": torch.tensor([[0.1, 2.0, -1.0], [3.0, 0.0, 0.0]]),
    }
    p = readout(outputs, "fraction", 0.5, torch.tensor([2.0, 4.0]))
    torch.testing.assert_close(p["hit_probability"], torch.sigmoid(outputs["occlusion"]))
    assert p["hit"].tolist() == [True, False]
    torch.testing.assert_close(p["distance"], torch.tensor([0.5, 4.0]))
    torch.testing.assert_close(p["fraction"], torch.tensor([0.25, 1.0]))
    torch.testing.assert_close(p["normal"], torch.tensor([[0.0, 0.6, 0.8], [0.0, 0.0, 0.0]]))
    assert torch.equal(p["albedo"], outputs["albedo"])
    assert p["material"].tolist() == [1, 0]


def test_readout_log1p_fraction_mode_gives_the_segment_fraction():
    """log1p-fraction: the head regresses log1p(t/l); the fraction is expm1 of it, kept in
    the segment, and the rest distance that fraction of the segment's rest length, at any
    voxel size."""
    y = torch.tensor([0.0, math.log1p(0.25), math.log1p(1.0), 3.0])
    rest_len = torch.tensor([2.0, 2.0, 0.5, 1e-9])
    for h in (1e-6, 1.0, 1e6):
        p = readout({"occlusion": torch.zeros(4), "distance": y, "normal": torch.ones(4, 3)},
                    "log1p-fraction", h, rest_len)
        torch.testing.assert_close(p["fraction"], torch.tensor([0.0, 0.25, 1.0, 1.0]))
        torch.testing.assert_close(p["distance"], torch.tensor([0.0, 0.5, 0.5, 1e-9]))
    zero_length = readout(
        {"occlusion": torch.zeros(1), "distance": torch.ones(1), "normal": torch.ones(1, 3)},
        "log1p-fraction", 1.0, torch.zeros(1))
    assert torch.isfinite(zero_length["fraction"]).all() and zero_length["distance"] == 0
    with pytest.raises(VDNIFError, match="voxel size"):
        readout({"occlusion": torch.zeros(1), "distance": torch.ones(1),
                 "normal": torch.ones(1, 3)}, "log1p-fraction", 0.0, torch.ones(1))


def test_readout_log_distance_mode_places_the_hit_at_d_over_h():
    """log-distance (the paper's written form, the ablation's): the head regresses
    log1p(d/h); the hit is h expm1(y) from the segment's start, kept in the segment."""
    h = 0.5
    y = torch.tensor([0.0, math.log1p(0.5), math.log1p(1.0), 5.0, 1.0])
    rest_len = torch.tensor([1.0, 1.0, 1.0, 1.0, 0.0])
    p = readout({"occlusion": torch.zeros(5), "distance": y, "normal": torch.ones(5, 3)},
                "log-distance", h, rest_len)
    # d = 0, 0.25, 0.5, beyond the segment (kept at its end), and a zero-length segment
    torch.testing.assert_close(p["distance"], torch.tensor([0.0, 0.25, 0.5, 1.0, 0.0]))
    torch.testing.assert_close(p["fraction"], torch.tensor([0.0, 0.25, 0.5, 1.0, 0.0]))


def test_the_distance_modes_are_the_fraction_its_log_and_the_papers_log_distance():
    """log1p(d/h) is the ablation's mode, named for what it is; a bare "log1p" is none."""
    assert DISTANCE_MODES == ("fraction", "log1p-fraction", "log-distance")
    with pytest.raises(VDNIFError, match="log1p"):
        NetworkConfig(distance_mode="log1p")


def test_predict_is_readout_of_forward_in_batches():
    torch.manual_seed(3)
    network = IntersectionNetwork(
        NetworkConfig(**SMALL, heads=Heads(albedo=True, material_count=3))
    )
    p0, p1 = torch.rand(2, 100, 3)
    rest_len = torch.rand(100) * 0.1
    batched = network.predict(p0, p1, rest_len, 0.05, batch=7)
    with torch.no_grad():
        whole = readout(network(p0, p1), network.config.distance_mode, 0.05, rest_len)
    assert batched.keys() == whole.keys()
    for key in whole:
        torch.testing.assert_close(batched[key], whole[key], rtol=1e-5, atol=1e-6)


def test_config_round_trip_and_validation():
    config = NetworkConfig(**SMALL, pe_form="pi", heads=Heads(albedo=False, material_count=4))
    assert NetworkConfig.from_dict(config.to_dict()) == config
    with pytest.raises(VDNIFError, match="unknown"):
        NetworkConfig.from_dict({**config.to_dict(), "dropout": 0.1})
    with pytest.raises(VDNIFError, match="distance_mode"):
        NetworkConfig(distance_mode="sigmoid")
    with pytest.raises(VDNIFError, match="width"):
        NetworkConfig(width=0)
    with pytest.raises(VDNIFError, match="material_count"):
        Heads(material_count=0)
    with pytest.raises(VDNIFError, match="heads"):
        Heads.from_header({"albedo": True})
    assert Heads.from_header({"albedo": False, "material_count": 3, "occlusion": True}) == Heads(
        False, 3
    )
    with pytest.raises(VDNIFError, match="heads"):
        Heads.from_header({"material_count": 3})


def test_benchmark_runs_on_tiny_sizes():
    from vdnif_addon.studies.network_bench import benchmark_network

    result = benchmark_network("cpu", segments=256, train_batch=128, repeats=1)
    rates = ("infer_segments_per_s", "serial_segments_per_s", "encode_segments_per_s",
             "mlp_segments_per_s", "train_samples_per_s")
    assert all(result[key] > 0 for key in rates)
    assert 0 < result["encode_fraction"] < 1 and result["encode_fraction"] + result[
        "mlp_fraction"
    ] == pytest.approx(1)
    assert 1 / result["serial_segments_per_s"] == pytest.approx(
        1 / result["encode_segments_per_s"] + 1 / result["mlp_segments_per_s"])
    assert (
        result["device"] == "cpu" and result["threads"] >= 1 and result["config"]["pe_bands"] == 3
    )


def test_auto_precision_is_bfloat16_only_where_the_device_has_it(monkeypatch):
    """``resolve_precision``: auto is bfloat16 on a device with bfloat16 instructions and
    float32 on one without (each made so here); an explicit choice is kept, bfloat16 refused
    in one line where the device lacks it, and a word that is no precision refused. The
    network benchmark times its inference at the resolved precision and says which."""
    from vdnif_addon.kernels import runtime
    from vdnif_addon.model.network import resolve_precision
    from vdnif_addon.studies.network_bench import benchmark_network

    cpu = torch.device("cpu")
    for native, auto in ((True, "bfloat16"), (False, "float32")):
        monkeypatch.setattr(runtime, "bfloat16_native", lambda device, native=native: native)
        assert resolve_precision("auto", cpu) == auto
        assert resolve_precision("float32", cpu) == "float32"
        result = benchmark_network("cpu", segments=256, train_batch=128, repeats=1)
        assert result["precision"] == auto
    with pytest.raises(VDNIFError, match="^precision bfloat16: cpu has no bfloat16") as error:
        resolve_precision("bfloat16", cpu)
    assert "\n" not in str(error.value)
    with pytest.raises(VDNIFError, match="precision 'half': choose one of auto, float32"):
        resolve_precision("half", cpu)


def test_one_thread_default_for_commands_worker_and_benchmark(monkeypatch):
    """Torch gets every core but the encoder's; the bench's --threads overrides it."""
    from vdnif_addon import threads
    from vdnif_addon.cli import build_parser

    for cores, expected in (({0, 1, 2, 3}, 3), ({0, 1}, 1), ({5}, 1)):
        monkeypatch.setattr(threads.os, "sched_getaffinity", lambda _, cores=cores: cores)
        assert threads.default_threads() == expected
    before = torch.get_num_threads()
    try:
        assert threads.use_threads(2) == 2 == torch.get_num_threads()
        assert threads.use_threads() == 1  # the 1-core affinity above
    finally:
        torch.set_num_threads(before)
    args = build_parser().parse_args(["bench-network", "--threads", "2"])
    assert args.threads == 2 and build_parser().parse_args(["bench-network"]).threads is None


def test_predict_overlaps_batches_without_changing_them():
    """The pipelined predict (encoder of batch k+1 in a worker thread) equals forward batch
    by batch, and its outputs carry no autograd history."""
    torch.manual_seed(4)
    network = IntersectionNetwork(
        NetworkConfig(**SMALL, heads=Heads(albedo=True, material_count=2)))
    with torch.no_grad():
        network.encoder.grid.table.normal_()
    p0, p1 = torch.rand(2, 1000, 3)
    rest_len = torch.rand(1000) * 0.1
    predicted = network.predict(p0, p1, rest_len, 0.05, batch=96)
    with torch.no_grad():
        parts = [readout(network(a, b), network.config.distance_mode, 0.05, r)
                 for a, b, r in zip(p0.split(96), p1.split(96), rest_len.split(96))]
    for key, value in predicted.items():
        assert torch.equal(value, torch.cat([part[key] for part in parts])), key
        assert not value.requires_grad


def test_empty_batches_and_non_finite_coordinates_are_safe():
    network = IntersectionNetwork(
        NetworkConfig(**SMALL, heads=Heads(albedo=True, material_count=2))
    )
    empty = network(torch.zeros(0, 3), torch.zeros(0, 3))
    assert empty["normal"].shape == (0, 3) and empty["material"].shape == (0, 2)
    assert network.predict(torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(0), 0.1)[
        "material"
    ].shape == (0,)
    odd = torch.tensor([[float("nan"), 0.5, float("inf")], [-float("inf"), 2.0, -3.0]])
    assert all(torch.isfinite(value).all() for value in network(odd, torch.rand(2, 3)).values())


def test_log1p_distance_head_starts_alive():
    """A ReLU distance head whose outputs all start at 0 never learns (dead ReLU)."""
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(distance_mode="log1p-fraction"))
    p0, p1 = torch.rand(2, 4096, 3)
    distance = network(p0, p1)["distance"]
    assert (distance > 0).float().mean() > 0.9


def albedo_field_network(seed):
    """A small network with an albedo field (``albedo_mode`` "hit") whose hash grids vary
    as trained ones do."""
    torch.manual_seed(seed)
    network = IntersectionNetwork(NetworkConfig(**{**SMALL, "albedo_mode": "hit"},
                                                heads=Heads(albedo=True, material_count=2)))
    with torch.no_grad():
        for grid in (network.encoder.grid, network.albedo_field.grid):
            grid.table.normal_()
    return network


def test_albedo_field_is_read_at_the_hit_it_is_given_or_predicts():
    """``albedo_mode`` "hit": the MLP loses its albedo columns (the task stays); forward gives
    the field's albedo at p0 + hit_frac (p1 - p0), and predict, batch by batch in the worker
    pipeline, the field's at p0 + fraction (p1 - p0), the fraction it predicts, on the
    candidate segments (the only ones that can place a hit), 0 on the others."""
    network = albedo_field_network(5)
    config = network.config
    assert network.head_sizes == Heads(albedo=True, material_count=2).sizes()
    assert network.mlp[-1].out_features == 1 + 1 + 3 + 2
    p0, p1 = torch.rand(2, 500, 3)
    hit_frac, rest_len = torch.rand(500), torch.rand(500) * 0.1
    assert "albedo" not in network(p0, p1)
    with torch.no_grad():
        outputs = network(p0, p1, hit_frac)
        at_hit = torch.sigmoid(network.albedo_field.mlp(
            network.albedo_field.grid(p0 + hit_frac[:, None] * (p1 - p0))))
    torch.testing.assert_close(outputs["albedo"], at_hit)
    with torch.no_grad():                   # half the segments are candidates
        probability = torch.sigmoid(outputs["occlusion"])
    median = float(probability.median())
    network.thresholds = Thresholds(median, median)
    predicted = network.predict(p0, p1, rest_len, 0.05, batch=64)
    point = p0 + predicted["fraction"][:, None] * (p1 - p0)
    candidate = predicted["candidate"]
    assert 0 < candidate.sum() < len(candidate)
    with torch.no_grad():
        torch.testing.assert_close(predicted["albedo"][candidate],
                                   network.field_at("albedo", point[candidate]))
        assert (predicted["albedo"][~candidate] == 0).all()
        whole = readout(network(p0, p1), config.distance_mode, 0.05, rest_len,
                        network.thresholds)
    assert whole.keys() | {"albedo"} == predicted.keys()
    for key in whole:
        torch.testing.assert_close(predicted[key], whole[key], rtol=1e-5, atol=1e-6)
    # The albedo varies with the point: a field, not a constant.
    assert predicted["albedo"][candidate].std(0).min() > 1e-3
    # Without an albedo head there is no field, whatever the mode.
    plain = IntersectionNetwork(NetworkConfig(**{**SMALL, "albedo_mode": "hit"},
                                              heads=Heads(albedo=False, material_count=1)))
    assert plain.albedo_field is None and "albedo" not in plain(p0, p1, hit_frac)
    with pytest.raises(VDNIFError, match="albedo_mode"):
        NetworkConfig(albedo_mode="texture")


def test_normal_field_is_read_at_the_hit_and_made_unit():
    """``normal_mode`` "hit": the MLP loses its normal columns (the task stays). forward gives
    the field's normal at p0 + hit_frac (p1 - p0) on the rows it is given (0 on the others),
    predict the field's at each candidate's predicted hit, unit, beside the albedo field's,
    and the readout of the MLP's heads for the rest; bfloat16 runs the field in bfloat16."""
    torch.manual_seed(7)
    config = NetworkConfig(**{**SMALL, "albedo_mode": "hit", "normal_mode": "hit"},
                           heads=Heads(albedo=True, material_count=2))
    network = IntersectionNetwork(config)
    with torch.no_grad():
        for grid in (network.encoder.grid, network.albedo_field.grid, network.normal_field.grid):
            grid.table.normal_()
    assert network.head_sizes == Heads(albedo=True, material_count=2).sizes()
    assert network.mlp[-1].out_features == 1 + 1 + 2
    assert list(network.point_fields()) == ["normal", "albedo"]
    p0, p1 = torch.rand(2, 500, 3)
    hit_frac, rest_len = torch.rand(500), torch.rand(500) * 0.1
    hit = torch.rand(500) < 0.3
    assert not {"normal", "albedo"} & set(network(p0, p1))
    with torch.no_grad():
        outputs = network(p0, p1, hit_frac, hit.nonzero().squeeze(1))
        point = p0 + hit_frac[:, None] * (p1 - p0)
        normal = network.normal_field.mlp(network.normal_field.grid(point))
    torch.testing.assert_close(outputs["normal"][hit], normal[hit])
    assert (outputs["normal"][~hit] == 0).all() and (outputs["albedo"][~hit] == 0).all()
    with torch.no_grad():
        torch.testing.assert_close(network(p0, p1, hit_frac)["normal"], normal)
        median = float(torch.sigmoid(outputs["occlusion"]).median())
    network.thresholds = Thresholds(median, median)
    predicted = network.predict(p0, p1, rest_len, 0.05, batch=64)
    candidate = predicted["candidate"]
    assert 0 < candidate.sum() < len(candidate)
    placed = p0 + predicted["fraction"][:, None] * (p1 - p0)
    with torch.no_grad():
        expected = torch.nn.functional.normalize(
            network.normal_field.mlp(network.normal_field.grid(placed[candidate])), dim=1)
        whole = readout(network(p0, p1), config.distance_mode, 0.05, rest_len,
                        network.thresholds)
    torch.testing.assert_close(predicted["normal"][candidate], expected)
    torch.testing.assert_close(predicted["normal"][candidate].norm(dim=1),
                               torch.ones(int(candidate.sum())))
    assert (predicted["normal"][~candidate] == 0).all()
    assert whole.keys() | {"albedo", "normal"} == predicted.keys()
    for key in whole:
        torch.testing.assert_close(predicted[key], whole[key], rtol=1e-5, atol=1e-6)
    network.precision = "bfloat16"
    half = network.predict(p0, p1, rest_len, 0.05, batch=64)
    field = copy.deepcopy(network.normal_field.mlp).to(torch.bfloat16)
    with torch.no_grad():
        placed = p0 + half["fraction"][:, None] * (p1 - p0)
        features = network.normal_field.grid(placed).to(torch.bfloat16)
        expected = torch.nn.functional.normalize(field(features).float(), dim=1)
    chosen = half["candidate"]
    torch.testing.assert_close(half["normal"][chosen], expected[chosen], rtol=1e-5, atol=1e-6)
    with pytest.raises(VDNIFError, match="normal_mode"):
        NetworkConfig(normal_mode="vertex")


def test_a_model_file_without_the_normal_mode_has_the_normal_head():
    """Files written before the normal field existed store no ``normal_mode``: they read as
    ``segment`` (their weights have the normal columns), while a new network gets the field."""
    stored = NetworkConfig().to_dict()
    assert stored.pop("normal_mode") == "hit"
    assert NetworkConfig.from_dict(stored).normal_mode == "segment"
    assert NetworkConfig.from_dict({**stored, "normal_mode": "hit"}).normal_mode == "hit"


def test_the_normal_field_has_its_own_grid():
    """The normal field's grid has ``normal_levels`` levels and 2^``normal_log2_table_size``
    rows (the encoder's base resolution, growth and features); the albedo field keeps the
    encoder's. Files written before it had its own grid store neither setting: they read the
    encoder's, which their field was built with."""
    config = NetworkConfig(**{**SMALL, "albedo_mode": "hit", "normal_mode": "hit"},
                           normal_levels=3, normal_log2_table_size=12, heads=Heads(albedo=True))
    network = IntersectionNetwork(config)
    grids = {name: network.point_fields()[name].grid for name in ("normal", "albedo")}
    assert (grids["normal"].levels, grids["normal"].log2_table_size) == (3, 12)
    assert (grids["albedo"].levels, grids["albedo"].log2_table_size) == (2, 10)
    for grid in (grids["normal"], grids["albedo"], network.encoder.grid):
        assert (grid.base_resolution, grid.growth, grid.feature_dim) == (8, 2.0, 3)
    stored = config.to_dict()
    del stored["normal_levels"], stored["normal_log2_table_size"]
    old = NetworkConfig.from_dict(stored)
    assert (old.normal_levels, old.normal_log2_table_size) == (2, 10)
    with pytest.raises(VDNIFError, match="normal_levels"):
        NetworkConfig(normal_levels=0)
    with pytest.raises(VDNIFError, match="normal field's hash grid"):
        NetworkConfig(normal_levels=12)


def test_predict_reads_the_device_once_whatever_its_batches():
    """Finding the candidates that read the albedo field reads the device on the host (on
    CUDA a wait for all work queued): once per call, not once per batch; the albedo is the
    field's at every candidate's predicted hit all the same."""
    torch.manual_seed(4)
    config = NetworkConfig(**{**SMALL, "albedo_mode": "hit"},
                           heads=Heads(albedo=True, material_count=1))
    network = IntersectionNetwork(config)
    p0, p1 = torch.rand(2, 500, 3)
    rest_len = torch.full((500,), 0.1)
    with torch.no_grad():                   # half the segments are candidates
        median = float(torch.sigmoid(network(p0, p1)["occlusion"]).median())
    network.thresholds = Thresholds(median, median)
    with counting_host_reads() as reads:
        predicted = network.predict(p0, p1, rest_len, 0.05, batch=64)   # 8 batches
    assert len(reads) <= 1, reads
    candidate = predicted["candidate"]
    assert 0 < candidate.sum() < len(candidate)
    point = p0 + predicted["fraction"][:, None] * (p1 - p0)
    with torch.no_grad():
        torch.testing.assert_close(predicted["albedo"][candidate],
                                   network.field_at("albedo", point[candidate]))
    assert (predicted["albedo"][~candidate] == 0).all()


def test_predict_keeps_float32_albedo_when_the_field_answers_in_float16(monkeypatch):
    """Under CUDA's autocast the albedo field answers in float16 and ``index_copy`` into
    the float32 pass does not promote it (the CPU's autocast does): predict casts it."""
    torch.manual_seed(3)
    config = NetworkConfig(**{**SMALL, "albedo_mode": "hit"},
                           heads=Heads(albedo=True, material_count=1))
    network = IntersectionNetwork(config)
    network.thresholds = Thresholds(1e-9, 1e-9)        # every segment a candidate
    field = network.field_at
    monkeypatch.setattr(network, "field_at", lambda name, points: field(name, points).half())
    p0, p1 = torch.rand(2, 50, 3)
    predicted = network.predict(p0, p1, torch.full((50,), 0.1), 0.05, batch=64)
    assert predicted["albedo"].dtype == torch.float32
    expected = field("albedo", p0 + predicted["fraction"][:, None] * (p1 - p0)).half().float()
    torch.testing.assert_close(predicted["albedo"], expected)


def test_the_render_refuses_a_network_on_another_device():
    """neural_passes checks the network's weights against the render's device before any
    launch ("meta" stands in for a GPU on a machine without one)."""
    from vdnif_addon.inference.neural_render import neural_passes

    network = IntersectionNetwork(NetworkConfig(**SMALL)).to("meta")
    with pytest.raises(VDNIFError, match="weights are on meta but the render runs on cpu"):
        neural_passes(network, None, None, None, None, None, device="cpu")


def test_bfloat16_precision_runs_both_mlps_in_bfloat16_and_reads_out_in_float32():
    """``precision`` "bfloat16": predict equals the readout of the MLPs run on bfloat16
    copies of their weights and inputs (the oracle; the hash grids' features stay float32),
    the albedo field's too, with float32 outputs; float32 is the default and differs from
    it, so the setting took effect."""
    network = albedo_field_network(6)
    config = network.config
    p0, p1 = torch.rand(2, 400, 3)
    rest_len = torch.rand(400) * 0.1
    with torch.no_grad():                   # half the segments are candidates
        median = float(torch.sigmoid(network(p0, p1)["occlusion"]).median())
    network.thresholds = Thresholds(median, median)
    assert network.precision == "float32"
    full = network.predict(p0, p1, rest_len, 0.05, batch=128)
    network.precision = "bfloat16"
    half = network.predict(p0, p1, rest_len, 0.05, batch=128)
    mlp = copy.deepcopy(network.mlp).to(torch.bfloat16)
    field = copy.deepcopy(network.albedo_field.mlp).to(torch.bfloat16)
    with torch.no_grad():
        raw = mlp(network.encoder(p0, p1).to(torch.bfloat16)).float()
        columns = dict(zip(network.mlp_heads, raw.split(list(network.mlp_heads.values()), 1)))
        outputs = {"occlusion": columns["occlusion"].squeeze(1),
                   "distance": torch.relu(columns["distance"].squeeze(1)),
                   "normal": columns["normal"], "material": columns["material"]}
        expected = readout(outputs, config.distance_mode, 0.05, rest_len, network.thresholds)
        point = p0 + expected["fraction"][:, None] * (p1 - p0)
        albedo = torch.sigmoid(field(network.albedo_field.grid(point).to(torch.bfloat16)).float())
    for key in expected:
        torch.testing.assert_close(half[key], expected[key], rtol=1e-5, atol=1e-6)
        assert half[key].dtype == full[key].dtype
    candidate = expected["candidate"]
    assert candidate.any()
    torch.testing.assert_close(half["albedo"][candidate], albedo[candidate], rtol=1e-5, atol=1e-6)
    assert half["albedo"].dtype == torch.float32
    assert not torch.equal(half["hit_probability"], full["hit_probability"])
