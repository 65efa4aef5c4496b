"""The import floors of docs/layout.md, read from the source with ``ast`` (nothing is imported).

- no circle: no module reaches itself through imports, lazy ones inside functions included;
- the packages stand on each other one way: ``esim_lite`` <- ``datagen`` <- ``model``; inside
  ``model``, ``data/`` imports neither ``inference/`` nor ``training/``, and ``inference/``
  never imports ``training/``;
- running a model never simulates: ``model/inference/`` imports of ``esim_lite`` only the
  shared floor (``esim_lite.core``) and of ``datagen`` only the readers of recordings and
  shards, and no model module that inference imports reaches for the simulator or datagen's
  generator either (``model/calibration.py``, which simulates, stands above inference).

Each failure lists the offending imports as ``module -> module (file:line)``.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("esim_lite", "datagen", "model")

SHARED_FLOOR = ("esim_lite.core",)
"""What every stage may import of the simulator's package: the records it shares."""

READERS = ("datagen.recording", "datagen.formats", "datagen.shard")
"""datagen's readers of recordings and shards, through which inference reads its input."""

SIMULATOR = ("esim_lite.render", "esim_lite.events", "esim_lite.sequence", "esim_lite.config",
             "esim_lite.geometry.trajectory", "esim_lite.geometry.object_sampling",
             "esim_lite.geometry.objects", "esim_lite.geometry.scene",
             "esim_lite.geometry.visibility")
"""The simulator proper: rendering, the event models, whole sequences and their settings,
trajectories and the scenes they move through."""

GENERATOR = ("datagen.generate", "datagen.sampling", "datagen.sensor_ranges",
             "datagen.textures", "datagen.config", "datagen.lock", "datagen.cli",
             "datagen.video")
"""datagen's generator: the recipe, the per-sequence draws and the run that writes shards."""

def _module_files() -> dict[str, Path]:
    """Dotted module name -> file, for every module of :data:`PACKAGES`."""
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


MODULES = _module_files()


def _resolve(name: str) -> str | None:
    """The module of ours that ``name`` (a module or a name inside one) lives in."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str, path: Path) -> dict[str, int]:
    """The modules of ours that ``module`` imports, each with the line of its first import."""
    found: dict[str, int] = {}
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, up level - 1
                parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            # ``from pkg import mod`` imports the module pkg.mod, ``from mod import name`` mod
            names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base
                     for alias in node.names]
        else:
            continue
        for name in names:
            target = _resolve(name)
            if target is not None and target != module:
                found.setdefault(target, node.lineno)
    return found


GRAPH = {module: _imports(module, path) for module, path in MODULES.items()}


def _edge(source: str, target: str) -> str:
    path = MODULES[source].relative_to(ROOT)
    return f"{source} -> {target} ({path}:{GRAPH[source][target]})"


def _under(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def _circles() -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
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
                out.append(sorted(component))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    return out


def _breaking(rule) -> list[str]:
    """Every import ``source -> target`` for which ``rule(source, target)`` is true."""
    return [_edge(s, t) for s in sorted(GRAPH) for t in sorted(GRAPH[s]) if rule(s, t)]


def test_the_graph_is_read_from_every_package():
    # a guard for the tests below: they pass vacuously on an empty or unresolved graph
    assert all(p in MODULES for p in PACKAGES)
    assert "esim_lite.core.events" in GRAPH["datagen.shard"]
    assert "model.inference.engines" in GRAPH["model.inference.reconstruct"]
    assert "model.inference.graph_export" in GRAPH["model.inference.quantize"]  # from-import


def test_no_module_imports_itself_through_others():
    circles = _circles()
    assert not circles, "import circles:\n" + "\n\n".join(
        "\n".join(_edge(s, t) for s in c for t in sorted(GRAPH[s]) if t in c) for c in circles)


def test_the_packages_import_only_downwards():
    def up(source: str, target: str) -> bool:
        return ((_under(source, ("esim_lite",)) and _under(target, ("datagen", "model")))
                or (_under(source, ("datagen",)) and _under(target, ("model",))))

    offending = _breaking(up)
    assert not offending, "imports up a floor:\n" + "\n".join(offending)


def test_inside_model_data_stands_below_inference_and_training():
    def up(source: str, target: str) -> bool:
        return ((_under(source, ("model.data",))
                 and _under(target, ("model.inference", "model.training")))
                or (_under(source, ("model.inference",)) and _under(target, ("model.training",))))

    offending = _breaking(up)
    assert not offending, "imports up a floor inside model:\n" + "\n".join(offending)


def _running() -> set[str]:
    """model.inference's modules and every model module they reach through model."""
    seen = {m for m in GRAPH if _under(m, ("model.inference",))}
    todo = list(seen)
    while todo:
        for target in GRAPH[todo.pop()]:
            if _under(target, ("model",)) and target not in seen:
                seen.add(target)
                todo.append(target)
    return seen


def test_running_a_model_never_simulates():
    running = _running()
    assert "model.calibration" not in running and "model.cli" not in running

    def outside_the_readers(source: str, target: str) -> bool:
        return (_under(source, ("model.inference",))
                and _under(target, ("esim_lite", "datagen"))
                and not _under(target, SHARED_FLOOR + READERS))

    def simulating(source: str, target: str) -> bool:
        return source in running and _under(target, SIMULATOR + GENERATOR)

    offending = _breaking(lambda s, t: outside_the_readers(s, t) or simulating(s, t))
    assert not offending, ("model.inference (or model code it imports) reaches for the "
                           "simulator or datagen's generator:\n" + "\n".join(offending))


def test_the_named_floors_exist():
    # a renamed module would silently drop out of the rules above
    for name in SHARED_FLOOR + READERS + SIMULATOR + GENERATOR:
        assert name in MODULES, name
