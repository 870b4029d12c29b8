"""The batch script run as users run it, for the tests of several files: a subprocess with
arguments after ``--``. It imports nothing of the core, so a Blender test file that runs the
script keeps to the extension's copy of the core (tests/project/test_module_identity.py)."""

import subprocess
import sys

from conftest import REPO

BATCH = REPO / "vdnif_addon" / "batch.py"


def run_batch(*args, timeout=120, env=None):
    result = subprocess.run([sys.executable, str(BATCH), "--", *map(str, args)],
                            capture_output=True, text=True, timeout=timeout, cwd=REPO, env=env)
    return result.returncode, result.stdout, result.stderr


def error_lines(stderr):
    return [line for line in stderr.splitlines() if line.startswith("vdnif: error:")]
