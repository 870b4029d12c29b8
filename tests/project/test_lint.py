"""The tree passes ruff with the repository's configuration (pyproject.toml: pyflakes,
pycodestyle, import order, lines of at most 99 characters)."""

import subprocess
import sys

from conftest import REPO


def test_ruff_finds_nothing():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(REPO)],
                            cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_reads_the_configuration(tmp_path):
    """The check can fail, and with the repository's limit: of a 99- and a 100-column line
    only the second is too long (ruff's default, 88, would flag both), and an unused import
    is reported."""
    sample = tmp_path / "sample.py"
    sample.write_text("import os\n\n"
                      "x = " + "1 + " * 23 + "123\n"                 # 99 columns
                      "y = " + "1 + " * 23 + "1234\n")               # 100 columns
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache",
                             "--output-format", "concise",
                             "--config", str(REPO / "pyproject.toml"), str(sample)],
                            cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 1
    assert "sample.py:1:8: F401" in result.stdout
    assert "sample.py:4:100: E501" in result.stdout and ":3:" not in result.stdout
