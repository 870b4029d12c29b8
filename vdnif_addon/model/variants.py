"""The three compared methods as configurations, trained and evaluated by the same code.

``lsnif``: static single pose, hash grid only, sigmoid t/l distance, fixed loss weights.
``deformed``: the same model trained on deformation-aware (many-pose) data.
``proposed``: deformation-aware data, F = 3 positional bands, log1p(t/l) distance, uncertainty
weighting.

The ablations are ``proposed`` with one of its three parts taken back to the baseline's
(``deformed``): ``proposed-no-pe`` (hash grid only, F = 0), ``proposed-no-log`` (LSNIF's
sigmoid t/l distance instead of the ReLU log1p(t/l)), ``proposed-no-uncertainty`` (fixed
loss weights).

The table of variants is ``settings.VARIANTS`` (torch-free: the panel and the parser read it);
this module builds their configurations and chooses one for a scene.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from ..errors import VDNIFError
from ..settings import DEFAULT_VARIANT, STATIC_VARIANT, VARIANTS, NetworkConfig, TrainConfig


@dataclass(frozen=True)
class Variant:
    """One method: its network, its training settings and which data it trains on."""

    name: str
    network: NetworkConfig
    train: TrainConfig
    deformed_data: bool
    """Train on many deformed poses (True) or on the single rest pose (False)."""


def choose_variant(requested: str | None, static: bool) -> tuple[str, str | None]:
    """(variant, note): what to train when ``requested`` is asked for (None: not asked) on
    a scene that is ``static`` (no armature or lattice deforms it) or not.

    Model only what the scene requires (DESIGN section 7): unasked, a static scene trains
    the static variant and a deforming one the default; an asked variant always wins. The
    note (None when there is nothing to say) tells the user which choice was made for them,
    or that a deformation-aware variant gains nothing on a static scene.
    """
    if requested is None:
        if static:
            return STATIC_VARIANT, (f"no armature or lattice deforms it: training the static "
                                    f"variant {STATIC_VARIANT}")
        return DEFAULT_VARIANT, None
    if static and variant_config(requested).deformed_data:
        return requested, (f"no armature or lattice deforms it: the deformation-aware "
                           f"variant {requested} gains nothing over the static variant "
                           f"{STATIC_VARIANT} here")
    return requested, None


def variant_config(name: str, **overrides: Any) -> Variant:
    """The named variant, with any NetworkConfig or TrainConfig field overridden by keyword."""
    if name not in VARIANTS:
        raise VDNIFError(f"unknown variant {name!r}; valid variants: {', '.join(VARIANTS)}")
    settings = {**VARIANTS[name], **overrides}
    network_fields = {f.name for f in dataclasses.fields(NetworkConfig)}
    train_fields = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = set(settings) - network_fields - train_fields - {"deformed_data"}
    if unknown:
        valid = sorted(network_fields | train_fields | {"deformed_data"})
        raise VDNIFError(f"unknown variant settings {sorted(unknown)}; valid: {valid}")
    return Variant(
        name=name,
        network=NetworkConfig(**{k: v for k, v in settings.items() if k in network_fields}),
        train=TrainConfig(**{k: v for k, v in settings.items() if k in train_fields}),
        deformed_data=settings["deformed_data"],
    )
