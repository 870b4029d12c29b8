"""Every public function and method of the core carries parameter and return annotations
(arrays and tensors with their shapes in jaxtyping's notation, ``Float[np.ndarray, "N 3"]``,
imported under ``TYPE_CHECKING`` with postponed annotations: no runtime dependency).

Annotations are read as written (``inspect.signature`` on postponed, string annotations),
never evaluated: jaxtyping is not a dependency, so ``typing.get_type_hints`` would fail.
"""

import importlib
import inspect
import pkgutil

import pytest

import vdnif_addon

# The pipeline's stage packages (bpy code, vdnif_addon/blender/, and the studies and commands
# above the core are not walked).
STAGES = ("geometry", "kernels", "tracing", "model", "training", "inference")

# Parameters that take no annotation by convention.
UNANNOTATED_KINDS = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
IMPLICIT = ("self", "cls")


def core_modules() -> list[str]:
    """Module names of the core: vdnif_addon's foundations and its stage packages."""
    names = []
    packages = [vdnif_addon, *(importlib.import_module(f"vdnif_addon.{stage}")
                               for stage in STAGES)]
    for package in packages:
        for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
            if not info.ispkg:
                names.append(info.name)
    return sorted(names)


def _public_callables(module) -> list[tuple[str, object]]:
    """(qualified name, function) of the functions defined in ``module`` and the methods,
    properties and ``__init__`` of its classes, leading-underscore names left out."""
    found = []
    for name, value in vars(module).items():
        if name.startswith("_") or getattr(value, "__module__", None) != module.__name__:
            continue
        if inspect.isfunction(value):
            found.append((name, value))
        elif inspect.isclass(value):
            for attribute, member in vars(value).items():
                if attribute.startswith("_") and attribute != "__init__":
                    continue
                if isinstance(member, (staticmethod, classmethod)):
                    member = member.__func__
                elif isinstance(member, property):
                    member = member.fget
                if inspect.isfunction(member) and member.__module__ == module.__name__:
                    found.append((f"{name}.{attribute}", member))
    return found


def missing_annotations(function) -> list[str]:
    """Names of ``function``'s parameters (and ``return``) that carry no annotation."""
    signature = inspect.signature(function, eval_str=False)
    missing = [name for name, parameter in signature.parameters.items()
               if parameter.annotation is inspect.Parameter.empty
               and parameter.kind not in UNANNOTATED_KINDS
               and not (name in IMPLICIT and next(iter(signature.parameters)) == name)]
    if signature.return_annotation is inspect.Signature.empty:
        missing.append("return")
    return missing


@pytest.mark.parametrize("name", core_modules())
def test_public_api_annotated(name):
    module = importlib.import_module(name)
    gaps = {qualified: missing for qualified, function in _public_callables(module)
            if (missing := missing_annotations(function))}
    assert not gaps, f"{name}: unannotated parameters/returns {gaps}"


def test_walk_finds_functions():
    """The walk sees module functions, methods, properties and constructors, and flags an
    unannotated one: the check above cannot pass by finding nothing."""
    from vdnif_addon.geometry import restmesh, voxels

    names = {qualified for qualified, _ in _public_callables(restmesh)}
    assert {"RestMesh.size", "RestMesh.heads", "Albedo.__init__"} <= names
    assert "check_range" in {q for q, _ in _public_callables(
        importlib.import_module("vdnif_addon.limits"))}
    assert len(_public_callables(voxels)) >= 5

    def bare(a, b: int, *rest, **options):
        return a

    assert missing_annotations(bare) == ["a", "return"]

