"""Numbers as every summary writes them, "n/a" where there is none: the batch commands' lines,
the panel's metrics line and the studies' tables."""

from __future__ import annotations


def value(number: float | None, digits: int = 4) -> str:
    """A number with ``digits`` significant digits, "n/a" for None."""
    return "n/a" if number is None else f"{number:.{digits}g}"


def percent(share: float | None, digits: int = 3) -> str:
    """A share in [0, 1] as a percentage, "n/a" for None."""
    return "n/a" if share is None else f"{100 * share:.{digits}g} %"
