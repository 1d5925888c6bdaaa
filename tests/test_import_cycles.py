"""No import circles among proprio's modules (issue #41): every import, also those inside functions, read by grimp
(the graph import-linter checks; the ``acyclic`` contract in pyproject.toml keeps sibling packages acyclic, this test
also catches a package's ``__init__`` and one of its own modules importing each other)."""
from __future__ import annotations

import grimp


def _cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """The strongly connected components of more than one module (or a module importing itself), each sorted:
    Tarjan's algorithm, iterative."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.find_modules_directly_imported_by(w)))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1 or v in graph.find_modules_directly_imported_by(v):
                    out.append(sorted(comp))
    return out


def test_the_cycle_finder_finds_a_planted_circle():
    graph = grimp.ImportGraph()
    for m in ("p", "p.a", "p.b", "p.c", "p.d"):
        graph.add_module(m)
    graph.add_import(importer="p.a", imported="p.b")
    graph.add_import(importer="p.b", imported="p.c")
    graph.add_import(importer="p.c", imported="p.a")
    graph.add_import(importer="p.d", imported="p.a")
    assert _cycles(graph) == [["p.a", "p.b", "p.c"]]


def test_no_import_cycle_among_proprio_modules():
    graph = grimp.build_graph("proprio", cache_dir=None)
    cycles = _cycles(graph)
    chains = []
    for comp in cycles:                      # one circle of each component, spelt out
        if len(comp) == 1:
            chains.append(f"{comp[0]} -> {comp[0]}")
            continue
        there, back = graph.find_shortest_chain(comp[0], comp[1]), graph.find_shortest_chain(comp[1], comp[0])
        chains.append(" -> ".join(list(there) + list(back[1:])))
    assert not cycles, "import circles:\n" + "\n".join(chains)
