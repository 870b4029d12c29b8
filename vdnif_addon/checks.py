"""The range and choice checks of every setting (``settings``), each failure a VDNIFError that
names the setting."""

from __future__ import annotations

from typing import Any

from .errors import VDNIFError


def check_int(name: str, value: int, low: int, high: int) -> None:
    """Raise a VDNIFError naming the setting unless ``value`` is an int in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise VDNIFError(f"setting {name} must be an integer in [{low}, {high}], got {value!r}")


def check_number(name: str, value: float, low: float, high: float) -> None:
    """Raise a VDNIFError naming the setting unless ``value`` is a real number in [low, high]
    (NaN never is)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        raise VDNIFError(f"setting {name} must be a number in [{low:g}, {high:g}], "
                         f"got {value!r}")


def check_choice(name: str, value: str, choices: Any) -> None:
    """Raise a VDNIFError naming the setting unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise VDNIFError(f"setting {name} must be one of {list(choices)}, got {value!r}")
