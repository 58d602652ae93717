"""The architecture's rules, checked on the source: the core imports no application, and no import circles."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("colorgrid", "colorgrid_apps", "train", "server")
APPLICATIONS = ("colorgrid_apps", "train", "server")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}


def imports(path: Path, known: dict) -> set[str]:
    """Project modules ``path`` imports, at the top or inside functions (lazily): ``from a import b`` is
    module ``a.b`` when that is a module, else ``a``."""
    found = set()
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            for alias in node.names:
                found.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base)
    return {name for name in found if name in known}


def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports(path, known) - {name} for name, path in known.items()}


def test_the_core_imports_no_application_not_even_lazily():
    bad = [(m, i) for m, deps in graph().items() if m.split(".")[0] == "colorgrid"
           for i in deps if i.split(".")[0] in APPLICATIONS]
    assert not bad, bad


def test_there_are_no_import_circles():
    g = graph()
    index, low, stack, on_stack, circles, counter = {}, {}, [], set(), [], [0]

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(g):
        if v not in index:
            visit(v)
    assert not circles, circles


def test_the_trainer_and_the_server_import_no_command_line():
    """Library code (evaluation, export, branching, the human-follower measures) lives in the core; only the
    command line and the viewer live in ``colorgrid_apps``."""
    bad = [(m, i) for m, deps in graph().items() if m.split(".")[0] in ("train", "server")
           for i in deps if i.split(".")[0] == "colorgrid_apps"]
    assert not bad, bad


def test_only_the_study_imports_the_study():
    """The study plugs into the play engine through its hooks (``server.backend.Plugin``, the hub's game source
    and listeners): nothing else under ``server`` imports ``server.study``, not even lazily."""
    bad = [(m, i) for m, deps in graph().items() if not m.startswith("server.study")
           for i in deps if i.startswith("server.study")]
    assert not bad, bad


LONG_ALLOWED: dict[str, str] = {}
"""Modules allowed over the size, each with its reason."""


def test_each_job_fits_a_file_a_reader_can_hold():
    """No module of any package over about 400 lines, the trainer about 350 (split one concern out instead)."""
    limits = {path: 360 if path == ROOT / "train" / "trainer.py" else 420
              for package in PACKAGES for path in (ROOT / package).rglob("*.py")}
    long = {str(p.relative_to(ROOT)): n for p, limit in limits.items() if (n := len(p.read_text().splitlines())) > limit}
    assert not set(long) - set(LONG_ALLOWED), {k: n for k, n in long.items() if k not in LONG_ALLOWED}
    assert all((ROOT / path).is_file() for path in LONG_ALLOWED), "an allowance names a module that is gone"


NOT_IN_THE_CHECKOUT = {"colorgrid/_data/": "the wheel's copy of the shipped folders, made when the wheel is built"}
"""Paths ARCHITECTURE.md names that a checkout does not hold, each with its reason."""


def test_every_repository_path_architecture_md_names_exists():
    """Each `path` ARCHITECTURE.md names under a folder of the repository (``colorgrid/configkit/``,
    ``server/play/offer.py``) is there: the map is corrected when the code moves."""
    import re

    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    folders = {p.name for p in ROOT.iterdir() if p.is_dir() and not p.name.startswith(".")}
    named = {m for m in re.findall(r"`([A-Za-z0-9_.-]+/[A-Za-z0-9_./-]*)`", text) if m.split("/")[0] in folders}
    assert len(named) > 20, named  # the map names the project's files
    missing = sorted(p for p in named - set(NOT_IN_THE_CHECKOUT) if not (ROOT / p).exists())
    assert not missing, missing
