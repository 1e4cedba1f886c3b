"""The import graph, drawn from the code: no stage imports a later stage or anything above the stages,
the shared modules import no stage, and the packages import one another without a cycle.

``python tests/test_layout.py`` prints the graph (package → the packages it imports), as README's
"Layout" draws it.
"""

import ast
import sys
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mitsuforest"
STAGES = ("config", "plan", "trees", "scene", "scan", "labels", "write")
SHARED = ("mitsuforest", "errors", "classes", "threads", "pools", "interrupts", "realism", "specs", "crs", "fields",
          "seeds", "textfiles")   # import no stage
ABOVE = ("survey", "pipeline", "cli", "__main__", "dataset", "helios", "twin", "compare", "torch", "testing")
# Imports from a stage to a later one that are still there, each with its way out; the test fails
# when one is added, and when one is gone but still listed here. Issue 29 emptied it: the last one,
# scan → labels, went when the echo kernel stopped labelling hits (it keeps what each echo hit, and
# the labels stage turns that into ids).
KNOWN: dict[tuple[str, str], str] = {}


def unit(module: str) -> str:
    """``mitsuforest.plan.types`` → ``plan``; ``mitsuforest`` → ``mitsuforest``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def module_name(path: Path) -> str:
    """``mitsuforest/plan/types.py`` → ``mitsuforest.plan.types``; a package's ``__init__.py`` → the package."""
    return ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")


def imports(path: Path) -> list[tuple[str, int]]:
    """(imported module, line) of every import of the package in one file, relative ones resolved,
    those inside functions included."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            names = [base] if node.module else [_module_or_package(base, a.name) for a in node.names]
            out += [(name, node.lineno) for name in names]
    return [(name, line) for name, line in out if name.split(".")[0] == "mitsuforest"]


def _module_or_package(package: str, name: str) -> str:
    """``from PACKAGE import NAME``: the module NAME when there is one, the module the package root imports
    NAME from on first use (``mitsuforest._API``: ``render`` is ``pipeline``'s), else PACKAGE (a name in it)."""
    if package == "mitsuforest" and name in _lazy_names():
        return f"mitsuforest.{_lazy_names()[name]}"
    folder = PACKAGE.parent.joinpath(*package.split("."))
    is_module = (folder / f"{name}.py").exists() or (folder / name / "__init__.py").exists()
    return f"{package}.{name}" if is_module else package


def _lazy_names() -> dict[str, str]:
    """``mitsuforest._API``, read from the package root's source (no import)."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    found = [node.value for node in tree.body if isinstance(node, ast.Assign)
             and any(isinstance(t, ast.Name) and t.id == "_API" for t in node.targets)]
    return ast.literal_eval(found[0])


def import_graph() -> dict[tuple[str, str], list[str]]:
    """(importing package, imported package) → the imports that make the edge (``file:line module``)."""
    edges = defaultdict(list)
    for path in sorted(PACKAGE.rglob("*.py")):
        here = unit(module_name(path))
        for name, line in imports(path):
            there = unit(name)
            if there != here:
                edges[(here, there)].append(f"{path.relative_to(PACKAGE.parent)}:{line} {name}")
    return dict(edges)


def backward(edges) -> set[tuple[str, str]]:
    """Edges from a stage to a later stage or above the stages, and from a shared module to any other."""
    out = set()
    for a, b in edges:
        if a in SHARED and b not in SHARED:
            out.add((a, b))
        elif a in STAGES and (b in ABOVE or (b in STAGES and STAGES.index(b) > STAGES.index(a))):
            out.add((a, b))
    return out


def cycles(edges) -> list[list[str]]:
    """The packages on a cycle, one list per strongly connected set of more than one (Tarjan)."""
    graph = defaultdict(set)
    for a, b in edges:
        graph[a].add(b)
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_every_package_is_placed():
    found = {unit(module_name(p)) for p in PACKAGE.rglob("*.py")}
    assert found == set(STAGES) | set(SHARED) | set(ABOVE)


def test_no_stage_imports_a_later_stage_or_the_layers_above():
    edges = import_graph()
    found = backward(edges)
    new = {e: edges[e] for e in sorted(found - set(KNOWN))}
    assert not new, f"imports against the pipeline's order: {new}"
    assert set(KNOWN) <= found, f"gone, so take them off KNOWN: {sorted(set(KNOWN) - found)}"


def test_the_packages_import_one_another_without_a_cycle():
    edges = {e for e in import_graph() if e not in KNOWN}
    assert cycles(edges) == []


def test_the_checks_catch_what_they_look_for():
    """A later stage imported by an earlier one, a shared module importing a stage, and a cycle."""
    assert backward({("plan", "scene"), ("scene", "plan"), ("errors", "write"), ("write", "pipeline"),
                     ("pipeline", "write")}) == {("plan", "scene"), ("errors", "write"), ("write", "pipeline")}
    assert cycles({("write", "helios"), ("helios", "pipeline"), ("pipeline", "write"), ("pipeline", "plan")}) == \
        [["helios", "pipeline", "write"]]
    read = [name for name, _ in imports(PACKAGE / "scene" / "__init__.py")]   # relative imports resolved
    assert "mitsuforest.plan.transforms" in read and "mitsuforest.scene.variant" in read
    assert [name for name, _ in imports(PACKAGE / "survey.py")].count("mitsuforest") == 1   # from . import __version__
    # the package root's names imported on first use count as the modules they come from
    assert _module_or_package("mitsuforest", "render") == "mitsuforest.pipeline"
    assert _module_or_package("mitsuforest", "make_plan") == "mitsuforest.survey"
    assert _module_or_package("mitsuforest", "__version__") == "mitsuforest"


def readme_graph() -> dict[str, set[str]]:
    """README's "Layout" graph without the shared modules: package → the packages it imports."""
    text = (PACKAGE.parent / "README.md").read_text()
    block = text.split("Without the shared modules:", 1)[1].split("```", 2)[1]
    graph = {}
    for line in block.splitlines():
        for entry in line.split(";"):
            if "→" in entry:
                a, _, b = entry.partition("→")
                graph[a.strip()] = {name.strip() for name in b.split(",") if name.strip()}
    return graph


def test_readme_draws_the_graph_the_code_has():
    """README's "Layout" lists, for every stage and layer above them, the packages it imports (the
    shared modules left out), as ``python tests/test_layout.py`` prints them."""
    drawn = {a: set() for a in (*STAGES, *ABOVE) if a != "__main__"}
    for a, b in import_graph():
        if a in drawn and b not in SHARED:
            drawn[a].add(b)
    assert readme_graph() == drawn


if __name__ == "__main__":
    graph = defaultdict(set)
    for a, b in import_graph():
        graph[a].add(b)
    order = [*STAGES, *ABOVE, *SHARED]
    for a in sorted(graph, key=order.index):
        flags = {b: " (!)" if (a, b) in KNOWN else "" for b in graph[a]}
        print(f"{a:10} → " + ", ".join(b + flags[b] for b in sorted(graph[a], key=order.index)))
    sys.exit(0)
