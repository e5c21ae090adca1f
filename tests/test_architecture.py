"""The layers of docs/architecture.md hold: no import runs back up the picture, and no module imports itself
round a circle.

Every ``import`` in ``benchtwin/`` counts, also those inside functions and under ``TYPE_CHECKING``: a lazy
import that runs back up is still a dependency. Run ``python -m pytest tests/test_architecture.py`` after
moving code; a failure names the importing module, the line and the layer it reaches.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "benchtwin"

#: the picture, from the bottom up: a module may import its own layer and the layers below it
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("benchtwin", "benchtwin._heap", "benchtwin.errors", "benchtwin.lag", "benchtwin.lti", "benchtwin.mdf",
              "benchtwin.mf4stream", "benchtwin.roles", "benchtwin.segments")),
    ("recording", ("benchtwin.recording",)),
    ("config", ("benchtwin.config",)),
    ("trace", ("benchtwin.trace",)),
    ("wire", ("benchtwin.wire",)),
    ("emulator", ("benchtwin.emulator",)),
    ("sensors", ("benchtwin.sensors",)),
    ("chain", ("benchtwin.chain",)),
    ("identification", ("benchtwin.identification",)),
    ("validation", ("benchtwin.validation",)),
    ("studies", ("benchtwin.studies",)),
    ("commands", ("benchtwin.commands", "benchtwin.cli")),
]

#: identification runs unchanged on real logs and never sees the truth: of the project it may read only these
IDENTIFICATION_MAY_IMPORT = ("base", "recording", "config", "identification")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _layer(module: str) -> int:
    best, best_len = -1, -1
    for k, (_name, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or (p != "benchtwin" and module.startswith(p + "."))) and len(p) > best_len:
                best, best_len = k, len(p)
    if best < 0:
        raise AssertionError(f"module {module} is in no layer of tests/test_architecture.py: add it to the picture")
    return best


def import_graph(root: Path = ROOT) -> dict[str, list[tuple[str, int]]]:
    """Module -> [(imported project module, line)], from the source text (nothing is executed)."""
    modules = {_module_name(p): p for p in root.rglob("*.py")}
    graph: dict[str, list[tuple[str, int]]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        is_pkg = path.name == "__init__.py"
        edges: list[tuple[str, int]] = []
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:  # relative import
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
            for t in targets:
                if t == "benchtwin" or t.startswith("benchtwin."):
                    while t not in modules and "." in t:
                        t = t.rsplit(".", 1)[0]
                    if t != name:
                        edges.append((t, node.lineno))
        graph[name] = edges
    return graph


def back_edges(graph: dict[str, list[tuple[str, int]]]) -> list[str]:
    """Imports that reach a higher layer, or that identification may not make."""
    out = []
    allowed_ident = {k for k, (n, _) in enumerate(LAYERS) if n in IDENTIFICATION_MAY_IMPORT}
    ident = next(k for k, (n, _) in enumerate(LAYERS) if n == "identification")
    for mod, edges in sorted(graph.items()):
        lm = _layer(mod)
        for target, line in edges:
            lt = _layer(target)
            if lt > lm:
                out.append(f"{mod}:{line} imports {target} ({LAYERS[lt][0]}) from the lower layer {LAYERS[lm][0]}")
            elif lm == ident and lt not in allowed_ident:
                out.append(f"{mod}:{line} imports {target} ({LAYERS[lt][0]}): identification must run on real "
                           "logs without the truth")
    return out


def cycles(graph: dict[str, list[tuple[str, int]]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w, _ in graph.get(v, []):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


GRAPH = import_graph()


def test_every_module_is_in_a_layer() -> None:
    for mod in GRAPH:
        _layer(mod)


def test_no_import_runs_back_up_the_layers() -> None:
    bad = back_edges(GRAPH)
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_no_import_circles() -> None:
    found = cycles(GRAPH)
    assert not found, "import circles:\n" + "\n".join(" <-> ".join(c) for c in found)


@pytest.mark.parametrize("edge", [("benchtwin.wire.codec", "benchtwin.sensors.ivt"),
                                  ("benchtwin.identification.motor", "benchtwin.trace"),
                                  ("benchtwin.config.vehicle", "benchtwin.identification._fit")])
def test_the_checker_sees_a_back_edge(edge: tuple[str, str]) -> None:
    """The checks can fail: a graph with one forbidden import added is caught."""
    g = {k: list(v) for k, v in GRAPH.items()}
    g[edge[0]].append((edge[1], 1))
    assert any(edge[0] in b and edge[1] in b for b in back_edges(g))


def test_the_checker_sees_a_circle() -> None:
    g = {k: list(v) for k, v in GRAPH.items()}
    g["benchtwin.chain.batch"].append(("benchtwin.chain.acquisition", 1))
    g["benchtwin.chain.acquisition"].append(("benchtwin.chain.batch", 1))
    assert any("benchtwin.chain.batch" in c for c in cycles(g))


def test_modules_over_500_lines_say_why() -> None:
    """A module over ~500 lines names, in its first lines, why it stays whole."""
    long = []
    for path in ROOT.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        if text.count("\n") > 520 and "Kept whole:" not in "\n".join(text.splitlines()[:12]):
            long.append(f"{path.relative_to(ROOT.parent)} ({text.count(chr(10))} lines)")
    assert not long, "modules over 500 lines without a 'Kept whole: ...' line at the top:\n" + "\n".join(long)
