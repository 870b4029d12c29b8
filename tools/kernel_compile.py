"""The first compile of each kernel module: seconds and output bytes of every Warp module of
``vdnif_addon/kernels`` compiled into an empty cache folder, for the CPU (what a first run on
a machine waits for) and, with ``--ptx ARCH``, to PTX for that CUDA architecture through
Warp's NVRTC (what a first CUDA run waits for; no GPU needed), with the options each module
compiled under. ``--checkout`` times another checkout's kernels (before a change); each
round runs in a fresh process, the checkouts alternating. ``--json`` is checked by the output
rule first.

    python tools/kernel_compile.py [--ptx 90] [--rounds 2] [--checkout OTHER] --json out/k.json
"""

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402

FORMAT = "vdnif-kernel-compile"
"""The figures' format mark: the output rule lets ``--json`` replace only the tool's own file."""

_ROUND = """
import importlib, json, os, pkgutil, sys, tempfile, time
checkout, arch = sys.argv[1], int(sys.argv[2])
sys.path.insert(0, checkout)
import warp as wp
from vdnif_addon import kernels
from vdnif_addon.kernels import runtime
runtime.init()
def older_checkouts_modules():    # a checkout from before runtime.kernel_modules
    names = [info.name for info in pkgutil.iter_modules(kernels.__path__)]
    found = {short: getattr(importlib.import_module(f"vdnif_addon.kernels.{short}"),
                            "WARP_MODULE", None) for short in names}
    return {short: name for short, name in found.items() if name}
modules = (runtime.kernel_modules() if hasattr(runtime, "kernel_modules")
           else older_checkouts_modules())
rows = {}
for short, name in modules.items():
    options = {key: wp.get_module(name).options[key] for key in ("fuse_fp", "enable_backward")}
    folder = tempfile.mkdtemp()
    start = time.perf_counter()
    if arch:
        wp.compile_aot_module(name, arch=arch, module_dir=folder, use_ptx=True)
        suffix = ".ptx"
    else:
        runtime.load(name, "cpu")
        folder, suffix = runtime.cache_dir(), ".o"
    seconds = time.perf_counter() - start
    size = sum(os.path.getsize(os.path.join(path, file)) for path, _, files in os.walk(folder)
               for file in files if file.endswith(suffix) and name in path + file)
    rows[short] = {"seconds": seconds, "bytes": size, **options}
print(json.dumps(rows))
"""


def compile_round(checkout: pathlib.Path, arch: int) -> dict:
    """One fresh process's compile of ``checkout``'s kernels into an empty cache folder."""
    with tempfile.TemporaryDirectory() as cache:
        result = subprocess.run([sys.executable, "-c", _ROUND, str(checkout), str(arch)],
                                env={**os.environ, "VDNIF_KERNEL_CACHE": cache},
                                capture_output=True, text=True, check=False)
    if result.returncode:
        last = (result.stderr.strip().splitlines() or ["no message"])[-1]
        raise VDNIFError(f"compiling the kernels of {checkout} failed: {last}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def commit_of(checkout: pathlib.Path) -> str:
    """The commit a checkout is at, "+modified" where its tracked files differ from it."""
    def git(*arguments):
        return subprocess.run(["git", "-C", str(checkout), *arguments], capture_output=True,
                              text=True, check=False).stdout.strip()
    commit = git("rev-parse", "HEAD") or "unknown"
    return commit + ("+modified" if git("status", "--porcelain", "--untracked-files=no")
                     else "")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ptx", type=int, default=0, metavar="ARCH",
                        help="compile to PTX for this CUDA architecture (e.g. 90), not the CPU")
    parser.add_argument("--rounds", type=int, default=1, help="compiles per checkout")
    parser.add_argument("--checkout", type=pathlib.Path, default=None,
                        help="another checkout whose kernels are timed too")
    parser.add_argument("--json", type=pathlib.Path, default=None, help="write the figures")
    args = parser.parse_args()
    if args.rounds < 1:
        raise VDNIFError(f"--rounds must be at least 1, not {args.rounds}")
    if args.checkout and not (args.checkout / "vdnif_addon" / "kernels").is_dir():
        raise VDNIFError(f"--checkout '{args.checkout}' holds no vdnif_addon/kernels")
    if args.json:
        check_output_file(args.json, "--json", "json")     # the output rule, before the work
    checkouts = {"this": ROOT, **({"other": args.checkout.resolve()} if args.checkout else {})}
    commits = {key: commit_of(path) for key, path in checkouts.items()}
    runs = {key: [] for key in checkouts}
    for _ in range(args.rounds):
        for key, checkout in checkouts.items():
            runs[key].append(compile_round(checkout, args.ptx))
            total = sum(row["seconds"] for row in runs[key][-1].values())
            print(f"{key} ({commits[key]}): {total:.1f} s, " + ", ".join(
                f"{name} {row['seconds']:.1f} s {row['bytes']:,} B"
                for name, row in runs[key][-1].items()), flush=True)
    summary = {key: {name: statistics.median(run[name]["seconds"] for run in rounds)
                     for name in rounds[0]} for key, rounds in runs.items()}
    for key, medians in summary.items():
        print(f"{key}: medians {json.dumps({k: round(v, 2) for k, v in medians.items()})}")
    if args.json:
        write_json_atomic(args.json, stamp({
            "format": FORMAT, "target": f"sm_{args.ptx} PTX" if args.ptx else "cpu",
            "commits": commits,
            "runs": runs, "medians": summary}), "kernel compile figures", indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=(VDNIFError,), prefix="kernel_compile: error: ")
