#!/usr/bin/env python3
"""Fails if the modules of a workspace crate import each other in a circle.

usage: tools/check_circles.py [--tests] [REPO]      (REPO defaults to this script's repository)

For every member of the workspace (`[workspace] members` in REPO/Cargo.toml) and every crate root
of it (src/lib.rs, src/main.rs, src/bin/*), a *module* is an item the root declares with
`mod name;` (the file src/name.rs or src/name/mod.rs, with everything under src/name/). Module
`a` depends on module `b` when code of `a` names `b` through

  - `crate::b::...` or `$crate::b::...`, in a `use` or anywhere in code;
  - `use crate::{b, c::d}` (each branch of the group);
  - `super::...` / `self::...` paths that lead into `b`;
  - `crate::Item` or `super::Item` reaching the crate root, when the root re-exports `Item` from
    `b` (`pub use b::Item;`, `pub use b::*`) — the dependency is on the module that defines it;
  - for code in the crate root itself, any path `b::...` (the root's `pub use` lines are its
    public face, not a dependency).

Comments and doc links are not code and do not count. Items under `#[cfg(test)]` (test modules,
test-only files) are left out: tests may use anything. `--tests` counts them too.

Prints every circle (a strongly connected set of two or more modules) with one place in the
source for each dependency in it, and exits 1 if there is any; exits 0 otherwise.
"""

import os
import sys
import tomllib
from dataclasses import dataclass, field

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rust_tokens import LexError, tokens  # noqa: E402

ROOT_NODE = "(crate root)"


@dataclass
class Crate:
    name: str
    root_file: str
    modules: dict = field(default_factory=dict)  # module -> list of (file, base path)
    reexports: dict = field(default_factory=dict)  # root name -> module
    globs: list = field(default_factory=list)  # modules the root re-exports with `*`
    root_items: set = field(default_factory=set)  # items defined in the root file
    defined: dict = field(default_factory=dict)  # module -> names it defines (for globs)
    edges: dict = field(default_factory=dict)  # (from, to) -> first "file:line: path"


def main(argv):
    include_tests = "--tests" in argv
    args = [a for a in argv if a != "--tests"]
    if len(args) > 1 or any(a.startswith("-") for a in args):
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    repo = args[0] if args else os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(repo, "Cargo.toml"), "rb") as f:
        members = tomllib.load(f)["workspace"]["members"]
    circles = 0
    checked = 0
    for member in members:
        for crate in crate_roots(repo, member):
            try:
                analyse(crate, include_tests)
            except (LexError, OSError) as e:
                print(f"{crate.name}: cannot read the sources: {e}", file=sys.stderr)
                return 2
            checked += 1
            for scc in strongly_connected(crate):
                circles += 1
                report(crate, scc)
    if circles:
        print(f"{circles} import circle(s): move the shared item down into the lower module")
        return 1
    print(f"no import circles in {checked} crate roots")
    return 0


def crate_roots(repo, member):
    src = os.path.normpath(os.path.join(repo, member, "src"))
    name = os.path.basename(os.path.normpath(os.path.join(repo, member))) or member
    roots = [os.path.join(src, "lib.rs"), os.path.join(src, "main.rs")]
    bin_dir = os.path.join(src, "bin")
    if os.path.isdir(bin_dir):
        for entry in sorted(os.listdir(bin_dir)):
            p = os.path.join(bin_dir, entry)
            roots.append(os.path.join(p, "main.rs") if os.path.isdir(p) else p)
    for root in roots:
        if os.path.isfile(root) and root.endswith(".rs"):
            label = name if root.endswith("lib.rs") else f"{name} ({os.path.relpath(root, repo)})"
            yield Crate(label, root)


# ------------------------------------------------------------------------------------------
# Reading one crate


def analyse(crate, include_tests):
    root_toks = list(tokens(read(crate.root_file)))
    scan_root(crate, root_toks, include_tests)
    for module, files in crate.modules.items():
        for path, base in files:
            toks = list(tokens(read(path)))
            crate.defined.setdefault(module, set()).update(defined_names(toks))
    for module, files in crate.modules.items():
        for path, base in files:
            scan_code(crate, path, list(tokens(read(path))), base, include_tests)
    scan_code(crate, crate.root_file, root_toks, [], include_tests)


def read(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def scan_root(crate, toks, include_tests):
    """The root's modules (and their files), its re-exports and the items it defines."""
    root_dir = os.path.dirname(crate.root_file)
    reexports = []
    for item in top_items(toks, include_tests):
        words = [t.text for t in item]
        head = strip_visibility(words)
        if head[:1] == ["mod"] and len(head) >= 3 and head[2] == ";":
            path_attr = attr_path(item)
            crate.modules[head[1]] = module_files(root_dir, head[1], path_attr, include_tests)
        elif head[:1] == ["use"] and head != words:  # `pub use` / `pub(crate) use`
            reexports.extend(use_tree(head[1:]))
        elif head[:1] != ["macro_rules"]:
            name = item_name(head)
            if name:
                crate.root_items.add(name)
    for first, leaves in reexports:
        if first in ("crate", "self"):
            first = leaves[0] if leaves and leaves[0] != "*" else first
            leaves = leaves[1:] if len(leaves) > 1 else leaves
        if first not in crate.modules:
            continue
        if "*" in leaves:
            crate.globs.append(first)
        for leaf in leaves:
            if leaf != "*":
                crate.reexports[leaf] = first


def top_items(toks, include_tests):
    """The items at depth 0 of a file, each a list of tokens with its attributes."""
    i, n = 0, len(toks)
    while i < n:
        start = i
        test_only = False
        while i < n and toks[i].text == "#":
            j = skip_group(toks, i + 1 + (toks[i + 1].text == "!"))
            test_only |= is_cfg_test(toks[i:j])
            i = j
        j = item_end(toks, i)
        if include_tests or not test_only:
            yield toks[start:j]
        i = max(j, i + 1)


def item_end(toks, i):
    """Index after the item starting at `i`: after its `;` at depth 0, or its first top-level
    `{...}` group (unless the item is an expression-like `const`/`static`/`use` ending in `;`)."""
    n = len(toks)
    while i < n:
        t = toks[i].text
        if t == ";":
            return i + 1
        if t in "([":
            i = skip_group(toks, i)
            continue
        if t == "{":
            j = skip_group(toks, i)
            if j < n and toks[j].text == ";":
                return j + 1
            if j < n and toks[j].text in (".", "?", "as", "else"):
                i = j
                continue
            return j
        i += 1
    return n


def skip_group(toks, i):
    """`toks[i]` opens a group (`(`, `[` or `{`): the index after its closing token. An
    attribute's `#[...]` starts at its `[`."""
    pairs = {"(": ")", "[": "]", "{": "}"}
    stack = []
    n = len(toks)
    while i < n:
        t = toks[i].text
        if toks[i].kind == "punct" and t in pairs:
            stack.append(pairs[t])
        elif toks[i].kind == "punct" and t in ")]}":
            if stack and stack[-1] == t:
                stack.pop()
            if not stack:
                return i + 1
        i += 1
    return n


def is_cfg_test(attr):
    words = [t.text for t in attr]
    return "cfg" in words and "test" in words and "not" not in words


def strip_visibility(words):
    if words[:1] == ["pub"]:
        if words[1:2] == ["("]:
            close = words.index(")")
            return words[close + 1 :]
        return words[1:]
    # Attributes come first in an item's tokens: drop them.
    while words[:1] == ["#"]:
        depth = 0
        for k, w in enumerate(words):
            if w == "[":
                depth += 1
            elif w == "]":
                depth -= 1
                if depth == 0:
                    words = words[k + 1 :]
                    break
        else:
            return []
    return strip_visibility(words) if words[:1] == ["pub"] else words


def item_name(head):
    for k, w in enumerate(head):
        if w in ("const", "static", "fn", "struct", "enum", "type", "trait", "union", "mod"):
            if k + 1 < len(head) and head[k + 1] not in ("fn", "{", "("):
                name = head[k + 1]
                return name if name != "mut" else (head[k + 2] if k + 2 < len(head) else None)
        if w in ("impl", "use", "extern", "macro_rules", "=", "{", ";"):
            return None
    return None


def attr_path(item):
    words = [t for t in item]
    for k in range(len(words) - 2):
        if words[k].text == "path" and words[k + 1].text == "=" and words[k + 2].kind == "str":
            return words[k + 2].text.strip('"')
    return None


def module_files(parent_dir, name, path_attr, include_tests):
    """The files of module `name` declared in a file of `parent_dir`: (file, base path)."""
    if path_attr:
        main = os.path.join(parent_dir, path_attr)
        child_dir = os.path.dirname(main)
    else:
        main = os.path.join(parent_dir, name + ".rs")
        child_dir = os.path.join(parent_dir, name)
        if not os.path.isfile(main):
            main = os.path.join(parent_dir, name, "mod.rs")
    if not os.path.isfile(main):
        return []
    files = [(main, [name])]
    for item in top_items(list(tokens(read(main))), include_tests):
        head = strip_visibility([t.text for t in item])
        if head[:1] == ["mod"] and len(head) >= 3 and head[2] == ";":
            for f, base in module_files(child_dir, head[1], attr_path(item), include_tests):
                files.append((f, [name] + base))
    return files


def defined_names(toks):
    names = set()
    for k in range(len(toks) - 1):
        t = toks[k].text
        if t in ("struct", "enum", "fn", "const", "static", "type", "trait", "union"):
            if toks[k + 1].kind == "ident":
                names.add(toks[k + 1].text)
        elif t == "macro_rules" and k + 2 < len(toks) and toks[k + 1].text == "!":
            names.add(toks[k + 2].text)
    return names


def use_tree(words):
    """`use` tree words (after `use`, up to `;`) -> [(first segment, [leaf names])]."""
    out = []

    def walk(k, prefix):
        # returns index after this tree
        segs = list(prefix)
        while k < len(words):
            w = words[k]
            if w == "{":
                k += 1
                while k < len(words) and words[k] != "}":
                    k = walk(k, segs)
                    if k < len(words) and words[k] == ",":
                        k += 1
                return k + 1
            if w in (",", "}", ";"):
                break
            if w == "as":
                segs[-1:] = [words[k + 1]]
                k += 2
                continue
            if w != "::":
                segs.append(w)
            k += 1
        if segs:
            first = segs[0]
            leaf = segs[-1]
            if leaf == "self":
                leaf = segs[-2] if len(segs) > 1 else leaf
            out.append((first, segs[1:] if first in ("crate", "self") else [leaf]))
        return k

    walk(0, [])
    return out


# ------------------------------------------------------------------------------------------
# Dependencies in code


def scan_code(crate, path, toks, base, include_tests):
    """Adds the dependencies of one file whose module path is `base` ([] for the root)."""
    here = base[0] if base else ROOT_NODE
    rel = os.path.relpath(path, os.path.dirname(os.path.dirname(crate.root_file)))
    mods = []  # (module name, brace depth at which it closes)
    depth = 0
    i, n = 0, len(toks)
    in_root_use = False
    while i < n:
        t = toks[i]
        text = t.text
        if text == "#" and i + 1 < n and toks[i + 1].text in ("[", "!"):
            j = skip_group(toks, i + 1 + (toks[i + 1].text == "!"))
            if not include_tests and is_cfg_test(toks[i:j]):
                if toks[i + 1].text == "!":
                    return  # the whole file is test-only
                i = skip_attrs(toks, j)
                i = item_end(toks, i)
                continue
            i = j
            continue
        if text == "{":
            depth += 1
        elif text == "}":
            depth -= 1
            while mods and mods[-1][1] > depth:
                mods.pop()
        elif text == "mod" and i + 2 < n and toks[i + 2].text == "{":
            mods.append((toks[i + 1].text, depth + 1))
        path_now = base + [m for m, _ in mods]
        owner = path_now[0] if path_now else ROOT_NODE
        prev = toks[i - 1].text if i else ""
        if not base and not mods and text == "use" and prev in ("pub", ")"):
            in_root_use = True  # a re-export of the root: its public face
        if text == ";":
            in_root_use = False
        if in_root_use or prev == "::":
            i += 1
            continue
        nxt = toks[i + 1].text if i + 1 < n else ""
        target_base, start = None, None
        if text == "crate" and nxt == "::":
            target_base, start = [], i + 2
        elif text == "super" and nxt == "::":
            k, ups = i, 0
            while k + 1 < n and toks[k].text == "super" and toks[k + 1].text == "::":
                ups, k = ups + 1, k + 2
            target_base, start = path_now[: max(len(path_now) - ups, 0)], k
        elif text == "self" and nxt == "::":
            target_base, start = path_now, i + 2
        elif not path_now and t.kind == "ident" and nxt == "::" and text in crate.modules:
            target_base, start = [], i
        if target_base is None:
            i += 1
            continue
        firsts, end = path_firsts(toks, start)
        for first in firsts:
            target = target_base[0] if target_base else resolve_root_name(crate, first)
            if target and target != owner:
                where = f"{rel}:{t.line}: {' '.join(x.text for x in toks[i:min(end, i + 12)])}"
                crate.edges.setdefault((owner, target), where)
        i = max(end, i + 1)


def skip_attrs(toks, i):
    while i + 1 < len(toks) and toks[i].text == "#" and toks[i + 1].text in ("[", "!"):
        i = skip_group(toks, i + 1 + (toks[i + 1].text == "!"))
    return i


def path_firsts(toks, k):
    """The first segment(s) of the path (or use-group) starting at `toks[k]`, and the index
    after it."""
    n = len(toks)
    if k < n and toks[k].text == "{":
        end = skip_group(toks, k)
        firsts = []
        expect = True
        depth = 0
        for t in toks[k + 1 : end - 1]:
            if t.text == "{":
                depth += 1
            elif t.text == "}":
                depth -= 1
            elif t.text == "," and depth == 0:
                expect = True
            elif expect and depth == 0 and t.kind == "ident":
                firsts.append(t.text)
                expect = False
        return firsts, end
    if k < n and toks[k].kind == "ident":
        return [toks[k].text], k + 1
    return [], k


def resolve_root_name(crate, name):
    """The module that item `name` of the crate root comes from (None for `self`)."""
    if name == "self":
        return None
    if name in crate.modules:
        return name
    if name in crate.reexports:
        return crate.reexports[name]
    if name in crate.root_items:
        return ROOT_NODE
    for module in crate.globs:
        if name in crate.defined.get(module, ()):
            return module
    return ROOT_NODE


# ------------------------------------------------------------------------------------------
# Circles


def strongly_connected(crate):
    """Tarjan's strongly connected components with two or more modules."""
    graph = {}
    for a, b in crate.edges:
        graph.setdefault(a, set()).add(b)
        graph.setdefault(b, set())
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                out.append(sorted(scc))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def report(crate, scc):
    print(f"{crate.name}: import circle {' <-> '.join(scc)}")
    members = set(scc)
    for (a, b), where in sorted(crate.edges.items()):
        if a in members and b in members:
            print(f"    {a} -> {b}    ({where})")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
