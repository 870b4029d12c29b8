"""The batch commands' output options: their argparse types, which carry the kind of file
each writes (so that the parser itself lists every output option), and the output rule
(``output_rule``) applied to all of them before any work."""

import argparse
import os
import pathlib


def names_scene(args):
    """Whether the options name a scene (--scene, --mesh or --blend)."""
    return any(getattr(args, name) is not None for name in ("scene", "mesh", "blend"))


class OutputPath(type(pathlib.Path())):
    """A path that an option names for its command to write; ``kind`` is the kind of file
    (``output_rule.KINDS``), or "folder". ``validate_arguments`` finds every output among the
    parsed options by this type and applies the output rule to it."""

    kind = "folder"

    def __repr__(self):             # shown as the plain path it is
        return f"{type(pathlib.Path()).__name__}({str(self)!r})"


def _output_type(kind: str):
    """The argparse type of an option naming an output of ``kind``; the type carries the
    kind (``output_kind``), so that the parser itself lists every output option."""

    def parse(text: str) -> OutputPath:
        # A file's name that names a folder (a trailing separator, ``.``, ``..``) is
        # refused: the path object alone would drop it, writing a file of the folder's name.
        if kind != "folder" and text.replace(os.sep, "/").rpartition("/")[2] in (
                "", ".", ".."):
            raise argparse.ArgumentTypeError(f"'{text}' names a folder, not a file")
        path = OutputPath(text)
        path.kind = kind
        return path

    parse.output_kind = kind
    parse.__name__ = f"{kind} output"
    return parse


output_file = _output_type("json")
"""--json PATH: a JSON report."""
output_markdown = _output_type("markdown")
"""--markdown, --performance, --results: a markdown file (or a section of one)."""
output_model = _output_type("model")
"""train's --out: a model file."""
output_folder = _output_type("folder")
"""An output folder (--out DIR, --plots, ...)."""


def run_inputs(args):
    """(path, label) of every file the command of ``args`` reads, for the output rule: the
    model files, the mesh or .blend, and a dataset that train reads."""
    paths = [(getattr(args, name), f"the {name} file") for name in ("mesh", "blend")
             if getattr(args, name, None) is not None]
    models = getattr(args, "model", None)
    for model in models if isinstance(models, list) else [models] if models else []:
        paths.append((pathlib.Path(str(model).rpartition("=")[2]), "the model file"))
    data = getattr(args, "data", None)
    if args.command == "train" and data is not None and not names_scene(args) and \
            pathlib.Path(data).is_dir():
        paths += [(path, "a dataset file") for path in pathlib.Path(data).iterdir()
                  if path.name.startswith("shard-") or path.suffix == ".manifest"]
    return paths


def check_outputs(args):
    """Applies the output rule (``safe_io.check_replace``) to every output option of
    ``args`` (those of type ``OutputPath``) before any work, and takes the output folders
    (``claim_folder``). train's --data is an output only with scene options."""
    from ..output_rule import run_inputs as reading
    from ..safe_io import check_output_file, claim_folder

    with reading(run_inputs(args), getattr(args, "force", False)):
        for name, path in sorted(vars(args).items()):
            if not isinstance(path, OutputPath):
                continue
            option = f"--{name.replace('_', '-')}"
            if name == "data" and not names_scene(args):
                continue                                # train reads it
            if path.kind == "folder":
                claim_folder(path, f"{option} folder")
            else:
                check_output_file(path, f"{option} model file" if path.kind == "model"
                                  else option, path.kind)


def check_places(places):
    """The output rule for the places a command derives from its options (``(path, option,
    kind)``, None paths skipped): folders are claimed, files checked, before any work."""
    from ..safe_io import check_output_file, claim_folder

    for path, option, kind in places:
        if path is None:
            continue
        if kind == "folder":
            claim_folder(path, f"{option} folder")
        else:
            check_output_file(path, option, kind)
