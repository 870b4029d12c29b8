"""Numbers as every summary writes them, "n/a" where there is none: the batch commands' lines,
the panel's metrics line and the studies' tables."""


def value(number, digits=4):
    """A number with ``digits`` significant digits, "n/a" for None."""
    return "n/a" if number is None else f"{number:.{digits}g}"


def percent(share, digits=3):
    """A share in [0, 1] as a percentage, "n/a" for None."""
    return "n/a" if share is None else f"{100 * share:.{digits}g} %"
