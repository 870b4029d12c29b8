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


def describe_preset(name: str, presets: dict[str, dict[str, Any]]) -> str:
    """One line for the panel's tooltip and the Apply Preset report: preset ``name``'s
    settings in the panel's words and what ``bench`` measured with them (PRESET_ERROR, rays/s,
    each where the file holds it); a preset that another one beats on both (balanced, where
    the sweep's front has no third point) says so."""
    preset = presets[name]
    measured = preset.get("measured", {})
    error, speed = measured.get(PRESET_ERROR), measured.get("render_rays_per_s")
    figures = [f"a distance error of {error:.3g} object units" if error is not None else "",
               f"{speed:,.0f} rays/s" if speed else ""]
    beaten_by = [other.title() for other in PRESET_NAMES if error is not None and speed
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
    """The presets written by ``bench`` (default: the shipped file); a missing or malformed
    file, one whose presets measured another error than PRESET_ERROR (an older bench's), or
    one where two presets share their settings (the panel offers three distinct points),
    raises VDNIFError."""
    path = pathlib.Path(path or PRESETS_FILE)
    try:
        data = json.loads(path.read_text())
        presets = data["presets"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise VDNIFError(f"presets file '{path}' cannot be read: {exc}") from None
    if not isinstance(presets, dict) or set(presets) != set(PRESET_NAMES) or any(
            not isinstance(preset, dict) or set(SETTINGS) - set(preset)
            or not isinstance(preset.get("measured"), dict)
            or PRESET_ERROR not in preset["measured"] for preset in presets.values()):
        raise VDNIFError(f"presets file '{path}' does not hold {', '.join(PRESET_NAMES)} "
                         f"with {', '.join(SETTINGS)} and a measured {PRESET_ERROR}")
    if data.get("error") != PRESET_ERROR:
        raise VDNIFError(f"presets file '{path}' measures its presets by "
                         f"{data.get('error')!r}, not {PRESET_ERROR!r}: run bench again")
    shared = [f"{a} and {b}" for i, a in enumerate(PRESET_NAMES) for b in PRESET_NAMES[i + 1:]
              if all(presets[a][key] == presets[b][key] for key in SETTINGS)]
    if shared:
        raise VDNIFError(f"presets file '{path}' gives {shared[0]} the same settings: run "
                         "bench again")
    return presets
