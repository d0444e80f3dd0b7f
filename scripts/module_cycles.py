#!/usr/bin/env python3
"""Module-level import cycles in the workspace's Rust crates.

Every source file is a module. Module `a` depends on module `b` when `a` names a path
into `b` (`use crate::b::X`, `super::X`, `crate::b::f()`, `pub use b::X`, grouped
imports included); a path resolves to the deepest module it reaches, so `super::X`
with `X` an item of the parent is a dependency on the parent — unless the parent only
re-exports `X` (`pub use child::X`, or a glob), which resolves to the module that
defines it: a facade is not a cycle. Test modules
(`#[cfg(test)] mod …`) are left out: a unit test reaching into its parent is not a
cycle of the library. Prints each strongly connected component of more than one module
and exits 1 if there is any.

Usage: scripts/module_cycles.py [CRATE_DIR ...]   (default: every workspace crate)
"""

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CRATES = [".", "engine", "engine/train", "envs", "evaluation", "bridge", "python_client"]

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


def rewrite_blocks(text, opening, rewrite):
    """`text` with every brace block that `opening` (a regex ending in `{`) starts
    replaced by `rewrite(header, body)`."""
    out, i = [], 0
    pattern = re.compile(opening)
    while True:
        m = pattern.search(text, i)
        if not m:
            out.append(text[i:])
            return "".join(out)
        depth, j = 1, m.end()
        while depth and j < len(text):
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        out.append(text[i : m.start()] + rewrite(text[m.start() : m.end()], text[m.end() : j]))
        i = j


def without_tests_and_comments(text):
    """The source with `#[cfg(test)]` modules and comments removed."""
    text = re.sub(r"//[^\n]*", "", text)
    test_module = r"#\[cfg\(test\)\]\s*(pub(\([^)]*\))?\s+)?mod\s+" + IDENT + r"\s*\{"
    return rewrite_blocks(text, test_module, lambda header, body: "")


def inline_modules_as_file(text):
    """`super::` inside an inline `mod name { … }` names the file's own module."""
    return rewrite_blocks(
        text,
        r"\bmod\s+" + IDENT + r"\s*\{",
        lambda header, body: header + body.replace("super::", "self::"),
    )


def expand_use_tree(tree):
    """`a::{b, c::{d, e}}` → [a::b, a::c::d, a::c::e]."""
    tree = re.sub(r"\s+", "", tree)
    brace = tree.find("{")
    if brace < 0:
        return [re.sub(r"\bas\b.*$", "", tree)]
    prefix, inner = tree[:brace], tree[brace + 1 : tree.rfind("}")]
    parts, depth, start = [], 0, 0
    for k, ch in enumerate(inner):
        depth += {"{": 1, "}": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            parts.append(inner[start:k])
            start = k + 1
    parts.append(inner[start:])
    return [p for part in parts if part for p in expand_use_tree(prefix + part)]


class Crate:
    def __init__(self, directory):
        self.dir = directory
        src = directory / "src"
        roots = [p for p in (src / "lib.rs", src / "main.rs") if p.exists()]
        self.modules = {}  # module path (tuple) -> file
        for root in roots:
            self._collect((), root)
        self.texts = {
            m: inline_modules_as_file(without_tests_and_comments(f.read_text()))
            for m, f in self.modules.items()
        }
        self.reexports = {m: self._reexports(m) for m in self.modules}

    def _reexports(self, module):
        """`name -> path` of the `pub use` items of `module`, and its glob targets."""
        named, globs = {}, []
        for m in re.finditer(r"\bpub(?:\([^)]*\))?\s+use\s+([^;]+);", self.texts[module]):
            for path in expand_use_tree(m.group(1)):
                segments = [s for s in path.split("::") if s]
                if segments[-1] == "*":
                    globs.append(segments[:-1])
                elif segments[-1] != "self":
                    named[segments[-1]] = segments
        return named, globs

    def defines(self, module, name):
        pattern = r"\bpub(?:\([^)]*\))?\s+(?:struct|enum|fn|trait|type|const|static|mod)\s+" + name + r"\b"
        return re.search(pattern, self.texts[module]) is not None

    def _collect(self, path, file):
        if path in self.modules:
            return
        self.modules[path] = file
        text = without_tests_and_comments(file.read_text())
        for m in re.finditer(r"(?:#\[path\s*=\s*\"([^\"]+)\"\]\s*)?(?:pub(?:\([^)]*\))?\s+)?mod\s+(" + IDENT + r")\s*;", text):
            explicit, name = m.group(1), m.group(2)
            base = file.parent if file.name in ("lib.rs", "main.rs", "mod.rs") else file.parent / file.stem
            if explicit:
                child = file.parent / explicit
            elif (base / f"{name}.rs").exists():
                child = base / f"{name}.rs"
            else:
                child = base / name / "mod.rs"
            if child.exists():
                self._collect(path + (name,), child)

    def resolve(self, module, path):
        """The deepest module that `path` (a list of segments) reaches from `module`."""
        head, rest = path[0], path[1:]
        if head == "crate":
            base = ()
        elif head == "super":
            base = module[:-1]
            while rest and rest[0] == "super":
                base, rest = base[:-1], rest[1:]
        elif head == "self":
            base = module
        elif module + (head,) in self.modules:  # a child module named directly
            base, rest = module + (head,), rest
        else:
            return None
        for k, segment in enumerate(rest):
            if base + (segment,) in self.modules:
                base = base + (segment,)
                continue
            return self.through_reexport(base, segment, depth=0) or base
        return base

    def through_reexport(self, module, name, depth):
        """The module defining `name` when `module` only re-exports it."""
        if depth > 8 or not re.fullmatch(IDENT, name) or self.defines(module, name):
            return None
        named, globs = self.reexports[module]
        if name in named:
            target = self.resolve(module, named[name][:-1] or ["self"])
            if target is not None and target != module:
                return self.through_reexport(target, name, depth + 1) or target
        for glob in globs:
            target = self.resolve(module, glob)
            if target is not None and target != module and (
                self.defines(target, name) or self.through_reexport(target, name, depth + 1)
            ):
                return self.through_reexport(target, name, depth + 1) or target
        return None

    def edges(self):
        """`module -> {module it depends on: the first path naming it}`."""
        graph = {m: {} for m in self.modules}
        for module in self.modules:
            text = self.texts[module]
            paths = []
            for m in re.finditer(r"\buse\s+([^;]+);", text):
                paths += expand_use_tree(m.group(1))
            paths += re.findall(r"\b(?:crate|super|self)(?:::" + IDENT + r")+", text)
            for p in paths:
                segments = [s for s in p.split("::") if s]
                if not segments:
                    continue
                target = self.resolve(module, segments)
                if target is not None and target != module:
                    graph[module].setdefault(target, p)
        return graph


def cycles(graph):
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
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
                found.append(sorted(component))

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    return found


def main(argv):
    crates = [ROOT / c for c in (argv or CRATES)]
    failed = False
    for directory in crates:
        graph = Crate(directory).edges()
        for component in cycles(graph):
            failed = True
            name = lambda m: "crate" + "".join("::" + s for s in m)
            print(f"{directory.relative_to(ROOT)}: cycle among {', '.join(map(name, component))}")
            for a in component:
                for b, path in sorted(graph[a].items()):
                    if b in component:
                        print(f"    {name(a)} -> {name(b)} ({path})")
    if not failed:
        print(f"no module cycles in {len(crates)} crates")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
