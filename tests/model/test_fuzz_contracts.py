"""A seeded fuzzer over the two plain-data contracts read from files a user hands over: a
model's metadata (``ModelMetadata.from_dict``, and ``load_model`` on whole files) and a
dataset's shard header and manifest (``read_dataset`` on a folder). Each case mutates a
valid document (random types, sizes, nesting and values at a random place); every outcome
must be a one-line VDNIFError naming the file, or a load whose result is sound (it writes
back to the same document, as strict JSON, with an albedo row per material), within a time
bound per case and in all: no other exception, no hang.

The fuzzer is seeded: a failure names its seed and case, which replay it exactly.
"""

import contextlib
import copy
import hashlib
import io
import json
import math
import random
import signal
import time

import numpy as np
import pytest
import torch
from dataset_headers import header_dict
from model_metadata import metadata_dict

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model import metadata as metadata_module
from vdnif_addon.model.metadata import ModelMetadata
from vdnif_addon.model.model_file import load_model, save_model
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.safe_io import json_text
from vdnif_addon.settings import Heads, NetworkConfig
from vdnif_addon.training import dataset
from vdnif_addon.training.header import DatasetHeader

CASES = 100
SEEDS = (0, 1)
CASE_LIMIT_S = 5            # one case; a hang is stopped here and fails the test
TOTAL_LIMIT_S = 20          # the cases of one seed and one contract
MODEL_FILE_EVERY = 10       # every 10th metadata case also goes through a whole model file

CONFIG = NetworkConfig(levels=1, log2_table_size=8, width=16, depth=1,
                       heads=Heads(albedo=True, material_count=2))
POSE = {"frame": 3.0, "bones": {"Bone.0": [0.1, -0.2, 0.3], "Bone.1": [0.0, 0.5, -0.5]},
        "deform": {"object": "Arm", "kind": "bend", "amount": 90.0}}


def base_metadata():
    return copy.deepcopy(metadata_dict(metadata_module, CONFIG,
                                       train_poses=[POSE, {"frame": 4.0}]))


def base_header():
    header = header_dict(materials=2, segments=4, pose_range=(0, 2))
    header["heads"]["material_slots"] = [0, 2]
    header["poses"][0].update(bones=copy.deepcopy(POSE["bones"]))
    return header


# --------------------------------------------------------------------------- the fuzzer


def nested(depth, leaf):
    """``leaf`` inside ``depth`` lists, built without recursion."""
    for _ in range(depth):
        leaf = [leaf]
    return leaf


class Fuzzer:
    """Random values and mutations; ``plain`` keeps to what JSON can hold (a header), else
    what a torch archive read with ``weights_only`` can (a model's metadata)."""

    def __init__(self, seed, plain):
        self.rng, self.plain = random.Random(seed), plain
        self.last = []                  # the mutations of the case under way

    def scalar(self):
        rng = self.rng
        return rng.choice([
            None, True, False, 0, 1, -1, 2, 3, 7, 2**31, -(2**63), 10**30, 10**400,
            0.0, -0.0, 0.5, 1.0, 1.5, 1e-320, 1e30, -1e30, 1e300, float("nan"),
            float("inf"), -float("inf"), "", "x", "0:2", "NaN", "é" * 50, "a" * 10_000,
            rng.random(), rng.randint(-10**6, 10**6), rng.uniform(-1e6, 1e6),
        ])

    def value(self, budget=3):
        rng = self.rng
        kind = rng.randrange(10)
        if budget <= 0 or kind < 5:
            return self.scalar()
        if kind == 5 and rng.random() < 0.2:
            small = rng.choice([0, 1, -1, 0.5, float("nan"), "x", None])
            return [small] * rng.choice([1000, 100_000])
        if kind == 5:
            return [self.value(budget - 1) for _ in range(rng.choice([0, 1, 2, 3, 5]))]
        if kind == 6:
            keys = ["frame", "occlusion", "dims", "x", ""] + ([] if self.plain else [1, (1, 2)])
            return {rng.choice(keys): self.value(budget - 1) for _ in range(rng.randrange(4))}
        if kind == 7:
            return nested(rng.choice([17, 50, 1000, 100_000]), self.scalar())
        if kind == 8 and not self.plain:
            return rng.choice([torch.zeros(rng.choice([0, 3, 1000])), torch.tensor(float("nan")),
                               (1, 2, 3), np.float64(0.5), b"bytes"])
        return [[self.scalar() for _ in range(3)] for _ in range(rng.choice([0, 1, 2, 5]))]

    def places(self, data):
        """Every (container, key) of ``data``, found without recursion."""
        found, stack = [], [data]
        while stack:
            item = stack.pop()
            pairs = (item.items() if isinstance(item, dict)
                     else enumerate(item) if isinstance(item, list) else ())
            for key, child in pairs:
                found.append((item, key))
                if len(found) < 5000:
                    stack.append(child)
        return found

    def mutate(self, data):
        """Applies one to three random mutations to ``data`` in place; returns what it did."""
        rng, done = self.rng, []
        for _ in range(rng.choice([1, 1, 2, 3])):
            places = self.places(data)
            if not places:
                break
            container, key = rng.choice(places)
            old = container[key]
            action = rng.choice(["replace", "replace", "delete", "add", "wrap", "number",
                                 "retype"])
            if action == "delete":
                del container[key]
            elif action == "add" and isinstance(container, dict):
                container[rng.choice(["colour", "frame", "grid", key])] = self.value()
            elif action == "add":
                container.append(self.value())
            elif action == "wrap":
                container[key] = rng.choice([[old], {"x": old}, nested(20, old)])
            elif action == "number" and isinstance(old, (int, float)):
                factor = rng.choice([-1, 0, 2, 1e30, 1e-30, float("nan"), float("inf")])
                container[key] = old * factor
            elif action == "retype" and isinstance(old, (list, dict)):
                container[key] = (dict(enumerate(old)) if isinstance(old, list) and not self.plain
                                  else tuple(old) if not self.plain else [old])
            elif action == "retype":
                container[key] = str(old) if not isinstance(old, str) else 7
            else:
                container[key] = self.value()
            done.append(f"{action} {key!r:.40}")
        return done


@contextlib.contextmanager
def case_limit(seconds):
    """Raises TimeoutError in a case that runs longer than ``seconds``."""
    def stop(*_):
        raise TimeoutError(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def check_refusal(exc, names):
    message = str(exc)
    assert isinstance(exc, VDNIFError), repr(exc)
    assert "\n" not in message and len(message) < 2000, message[:3000]
    assert names in message, message


def run_cases(seed, plain, one_case):
    """Runs CASES cases of ``one_case(fuzzer, index)``; a case that raises anything but the
    checked outcome fails the test naming the seed, the case and its mutations."""
    fuzzer = Fuzzer(seed, plain)
    outcomes = {"refused": 0, "loaded": 0}
    start = time.monotonic()
    for index in range(CASES):
        try:
            with case_limit(CASE_LIMIT_S):
                outcomes[one_case(fuzzer, index)] += 1
        except Exception as exc:
            pytest.fail(f"seed {seed} case {index}: {type(exc).__name__}: {str(exc)[:500]} "
                        f"({fuzzer.last})")
    seconds = time.monotonic() - start
    assert seconds < TOTAL_LIMIT_S, seconds
    return outcomes


# --------------------------------------------------------------------------- the model


@pytest.fixture(scope="module")
def network():
    torch.manual_seed(0)
    return IntersectionNetwork(CONFIG)


def sound_metadata(metadata, path):
    """A loaded metadata is what the readers may trust: it writes back to itself as strict
    JSON, with an albedo row per material and thresholds in (0, 1]."""
    again = ModelMetadata.from_dict(json.loads(json_text(metadata.to_dict(), "fuzz")), path)
    assert again == metadata
    assert len(metadata.albedo_table) >= metadata.network_config.heads.material_count
    assert 0 < metadata.thresholds.candidate <= metadata.thresholds.occlusion <= 1
    assert np.isfinite(metadata.albedo_colors()).all()


@pytest.mark.parametrize("seed", SEEDS)
def test_mutated_model_metadata_is_refused_on_one_line_or_loads_sound(seed, network,
                                                                      tmp_path):
    valid = ModelMetadata.from_dict(base_metadata(), "base.vdnif")     # valid as made
    sound_metadata(valid, "base.vdnif")
    saved = tmp_path / "fuzz.vdnif"

    def one_case(fuzzer, index):
        data = base_metadata()
        fuzzer.last = fuzzer.mutate(data)
        through_file = index % MODEL_FILE_EVERY == 0 and max_depth(data) < 200
        path = str(saved) if through_file else "fuzz.vdnif"
        try:
            if through_file:
                write_raw_model(saved, network, data)
                loaded_network, metadata = load_model(saved)
                assert loaded_network.config == metadata.network_config
            else:
                metadata = ModelMetadata.from_dict(data, path)
        except VDNIFError as exc:
            check_refusal(exc, f"model file {path}")
            return "refused"
        sound_metadata(metadata, path)
        return "loaded"

    outcomes = run_cases(seed, False, one_case)
    assert outcomes["refused"] > CASES // 2 and outcomes["loaded"] > 0, outcomes


def max_depth(data):
    depth, stack = 0, [(data, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, (dict, list, tuple)):
            depth = max(depth, level)
            stack.extend((child, level + 1) for child in
                         (item.values() if isinstance(item, dict) else item))
    return depth


def write_raw_model(path, network, data):
    """A model file of ``network`` whose metadata is ``data`` as given (no check): a valid
    file written by ``save_model``, its payload replaced with a matching checksum."""
    save_model(path, network, ModelMetadata.from_dict(base_metadata(), str(path)))
    archive = torch.load(path, weights_only=True)
    inner = torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), weights_only=True)
    inner["metadata"] = data
    buffer = io.BytesIO()
    torch.save(inner, buffer)
    payload = buffer.getvalue()
    archive["payload"] = torch.frombuffer(bytearray(payload), dtype=torch.uint8)
    archive["sha256"] = hashlib.sha256(payload).hexdigest()
    torch.save(archive, path)


# --------------------------------------------------------------------------- the dataset

DEEP = "__nested__"


def json_with_depth(data):
    """``data`` as JSON text, NaN kept, its nested lists of over 100 levels written as text
    (``json.dumps`` would recurse)."""
    deep = []

    def swap(value):
        if isinstance(value, list) and max_depth(value) > 100:
            deep.append(max_depth(value))
            return f"{DEEP}{len(deep) - 1}"
        if isinstance(value, dict):
            return {key: swap(child) for key, child in value.items()}
        if isinstance(value, list):
            return [swap(child) for child in value]
        return value

    text = json.dumps(swap(data))
    for index, depth in enumerate(deep):
        text = text.replace(f'"{DEEP}{index}"', "[" * depth + "]" * depth)
    return text


def sound_header(header, where):
    again = DatasetHeader.from_dict(json.loads(json_text(header.to_dict(), "fuzz")), where)
    assert again == header
    assert len(header.albedo_table) >= header.heads.material_count
    assert all(math.isfinite(value) for row in header.albedo_table for value in row)
    assert header.pose_range[1] - header.pose_range[0] == len(header.poses)


@pytest.mark.parametrize("seed", SEEDS)
def test_mutated_dataset_headers_are_refused_on_one_line_or_read_sound(seed, tmp_path):
    records = {name: np.zeros((4, *shape), dtype)
               for name, (dtype, shape) in dataset.ARRAYS.items()}
    dataset.write_shard(tmp_path, "shard-000000-000002", records,
                        DatasetHeader.from_dict(base_header(), "base"))
    header_path = tmp_path / "shard-000000-000002.json"
    manifest_path = tmp_path / dataset.MANIFEST
    good_manifest = json.loads(manifest_path.read_text())
    sound_header(dataset.read_dataset(tmp_path)[0].header, "base")

    def one_case(fuzzer, index):
        header, manifest = base_header(), copy.deepcopy(good_manifest)
        fuzzer.last = fuzzer.mutate(manifest if index % 5 == 4 else header)
        header_path.write_text(json_with_depth(header))
        manifest_path.write_text(json_with_depth(manifest))
        try:
            merged, shards = dataset.read_dataset(tmp_path)
        except VDNIFError as exc:
            check_refusal(exc, str(tmp_path))
            return "refused"
        sound_header(merged.header, "fuzz")
        assert merged.segments == sum(len(shard["pose"]) for shard in shards)
        return "loaded"

    outcomes = run_cases(seed, True, one_case)
    assert outcomes["refused"] > CASES // 2 and outcomes["loaded"] > 0, outcomes
