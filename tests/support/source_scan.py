"""Lines of the extension's and the tools' sources that match a pattern: what the tests that
keep a contract's string keys inside its own module scan. Imports no copy of the core."""

FOLDERS = ("vdnif_addon", "operators", "panels", "tools")


def matching_lines(repo, pattern, allowed):
    """``path:line: text`` of each line matching ``pattern`` (a compiled regex) in ``repo``'s
    root modules and its FOLDERS, but for the module at ``allowed`` (a relative path)."""
    paths = [*repo.glob("*.py"),
             *(path for folder in FOLDERS for path in (repo / folder).rglob("*.py"))]
    found = []
    for path in sorted(paths):
        relative = path.relative_to(repo).as_posix()
        if relative == str(allowed):
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                found.append(f"{relative}:{number}: {line.strip()}")
    return found
