"""Speed/accuracy presets: the fast / balanced / accurate settings that the ``bench`` command
measured and derived (``studies/pareto.py``), as the panel, the resolution suggestion and the
CLI read them."""

from __future__ import annotations

import json
import pathlib
from typing import Any

from .errors import VDNIFError

PRESETS_FILE = pathlib.Path(__file__).with_name("presets.json")
PRESETS_FORMAT = "vdnif-presets"
"""The presets file's own mark (its ``format`` key): ``bench`` may replace it."""
PRESET_NAMES = ("fast", "balanced", "accurate")
SETTINGS = ("resolution", "levels", "log2_table_size", "pe_bands", "width", "steps")
PRESET_VARIANT = "proposed"
"""The variant ``bench`` trains every point of its sweep with: a preset's settings are that
variant's, so applying one chooses it too (under Automatic its positional bands would give
way to the variant's own)."""
PRESET_ERROR = "common_vs_true_distance_mae"
"""The error the presets' front minimizes and each preset's ``measured`` holds: distance MAE
against the true reference (object units) over the common pixel set of the sweep's points
that predict hits (DESIGN section 10). A presets file names it as its ``error``."""


SPEED_ROUNDS = "render_rays_per_s_rounds"
"""A sweep point's rays/s in each of ``bench``'s timing rounds (its ``render_rays_per_s`` is
their median), kept beside it in bench.json and in a preset's ``measured``: their spread is
the timing's noise, and whether two speeds differ measurably is read from them
(``studies.pareto.measurably_faster``)."""


def describe_preset(name: str, presets: dict[str, dict[str, Any]]) -> str:
    """One line for the panel's tooltip and the Apply Preset report: preset ``name``'s
    settings in the panel's words and what ``bench`` measured with them (PRESET_ERROR, rays/s,
    each where the file holds it); a preset that another one of ``presets`` beats on both
    (balanced, where the sweep's front has no third point) says so."""
    preset = presets[name]
    measured = preset.get("measured", {})
    error, speed = measured.get(PRESET_ERROR), measured.get("render_rays_per_s")
    figures = [f"a distance error of {error:.3g} object units" if error is not None else "",
               f"{speed:,.0f} rays/s" if speed else ""]
    beaten_by = [other.title() for other in PRESET_NAMES if other in presets
                 and error is not None and speed
                 and _beats(presets[other].get("measured", {}), error, speed)]
    return (f"{name.title()}: the {PRESET_VARIANT.title()} variant at resolution "
            f"{preset['resolution']}, {preset['levels']} hash-grid levels of "
            f"2^{preset['log2_table_size']} entries, {preset['pe_bands']} positional-encoding "
            f"bands, width {preset['width']}, {preset['steps']:,} steps"
            + (f"; bench measured {' and '.join(f for f in figures if f)}" if any(figures)
               else "")
            + (f" ({' and '.join(beaten_by)} measured no slower and no less accurate: the "
               "sweep's front has no third point, and this one lies nearest it)"
               if beaten_by else ""))


def _beats(measured: dict[str, Any], error: float, speed: float) -> bool:
    """Whether figures ``measured`` are at least as good as ``error`` and ``speed`` on both
    and better on one."""
    other_error = measured.get(PRESET_ERROR)
    other_speed = measured.get("render_rays_per_s")
    return (other_error is not None and bool(other_speed) and other_error <= error
            and other_speed >= speed and (other_error, other_speed) != (error, speed))


def load_presets(path: str | pathlib.Path | None = None) -> dict[str, dict[str, Any]]:
    """The presets written by ``bench`` (default: the shipped file), by name: those it
    offers, which ``read_presets`` checks."""
    return read_presets(path)[0]


def read_presets(path: str | pathlib.Path | None = None
                 ) -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
    """(presets, dropped) of the file ``bench`` wrote (default: the shipped file): the
    presets it offers by name, and the reason, one line, of each name of PRESET_NAMES that
    it dropped (measured no faster than the next more accurate one). Each name is either
    offered or dropped, and one at least is offered; a file without ``dropped`` (written
    before presets could be) drops none. A missing or malformed file, one that offers a name
    it also drops or neither offers nor drops one, one whose presets measured another error
    than PRESET_ERROR (an older bench's), or one where two presets share their settings
    (the panel offers distinct points), raises VDNIFError."""
    path = pathlib.Path(path or PRESETS_FILE)
    try:
        data = json.loads(path.read_text())
        presets, dropped = data["presets"], data.get("dropped", {})
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise VDNIFError(f"presets file '{path}' cannot be read: {exc}") from None
    if not isinstance(presets, dict) or not isinstance(dropped, dict) or any(
            name not in PRESET_NAMES for name in (*presets, *dropped)) or any(
            not isinstance(preset, dict) or set(SETTINGS) - set(preset)
            or not isinstance(preset.get("measured"), dict)
            or PRESET_ERROR not in preset["measured"] for preset in presets.values()) or any(
            not isinstance(reason, str) or not reason.strip() for reason in dropped.values()):
        raise VDNIFError(f"presets file '{path}' does not hold {', '.join(PRESET_NAMES)}, "
                         f"each a preset with {', '.join(SETTINGS)} and a measured "
                         f"{PRESET_ERROR} or dropped with its reason")
    both = [name for name in PRESET_NAMES if name in presets and name in dropped]
    neither = [name for name in PRESET_NAMES if name not in presets and name not in dropped]
    if both or neither or not presets:
        raise VDNIFError(f"presets file '{path}' "
                         + (f"both offers and drops {both[0]}" if both else
                            f"neither offers nor drops {neither[0]}" if neither else
                            "drops every preset")
                         + ": run bench again")
    if data.get("error") != PRESET_ERROR:
        raise VDNIFError(f"presets file '{path}' measures its presets by "
                         f"{data.get('error')!r}, not {PRESET_ERROR!r}: run bench again")
    offered = [name for name in PRESET_NAMES if name in presets]
    shared = [f"{a} and {b}" for i, a in enumerate(offered) for b in offered[i + 1:]
              if all(presets[a][key] == presets[b][key] for key in SETTINGS)]
    if shared:
        raise VDNIFError(f"presets file '{path}' gives {shared[0]} the same settings: run "
                         "bench again")
    return presets, dropped
