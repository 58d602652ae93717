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


def test_each_job_of_the_server_and_the_trainer_fits_a_file_a_reader_can_hold():
    """No module of the server over about 400 lines, the trainer about 350 (split one concern out instead)."""
    limits = {path: 360 if path.name == "trainer.py" else 420
              for path in [*(ROOT / "server").rglob("*.py"), ROOT / "train" / "trainer.py"]}
    long = {str(p.relative_to(ROOT)): n for p, limit in limits.items() if (n := len(p.read_text().splitlines())) > limit}
    assert not long, long
