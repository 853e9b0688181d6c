#!/usr/bin/env python3
"""Fails if a Rust function is longer than a limit.

usage: tools/check_fn_len.py MAX_LINES DIR_OR_FILE...
  e.g. tools/check_fn_len.py 120 learner/src launch/src serve/src src

A function's length is the lines from the one holding `fn` to the one holding its closing `}`,
both included (attributes and doc comments above it do not count; a nested function counts in
its own right and inside its parent). Declarations without a body (trait methods, `extern`
functions) have no length; `fn(u8) -> u8` types, closures and `Fn` bounds are not functions.
Comments, strings (raw strings too) and character literals are read as such, so a `{` in them
never counts. Prints every function over the limit, longest first, and exits 1 if there is any.
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rust_tokens import LexError, tokens  # noqa: E402


def functions(src):
    """(name, first line, last line) of every function with a body in `src`."""
    toks = list(tokens(src))
    n = len(toks)
    out = []
    for i, t in enumerate(toks):
        if t.text != "fn" or t.kind != "ident" or i + 1 >= n or toks[i + 1].kind != "ident":
            continue
        # The signature ends at the first `{` or `;` outside parentheses and brackets
        # (`[u8; 4]` holds a `;`, `impl Fn() -> [u8; 2]` too).
        depth = 0
        j = i + 2
        while j < n:
            s = toks[j].text
            if toks[j].kind == "punct":
                if s in "([":
                    depth += 1
                elif s in ")]":
                    depth -= 1
                elif depth == 0 and s in "{;":
                    break
            j += 1
        if j >= n or toks[j].text == ";":
            continue
        level = 0
        k = j
        while k < n:
            if toks[k].kind == "punct":
                if toks[k].text == "{":
                    level += 1
                elif toks[k].text == "}":
                    level -= 1
                    if level == 0:
                        break
            k += 1
        if k >= n:
            raise LexError(f"line {t.line}: fn {toks[i + 1].text} has no closing brace")
        out.append((toks[i + 1].text, t.line, toks[k].line))
    return out


def rust_files(target):
    if os.path.isfile(target):
        yield target
        return
    for dirpath, dirnames, filenames in os.walk(target):
        dirnames.sort()
        for f in sorted(filenames):
            if f.endswith(".rs"):
                yield os.path.join(dirpath, f)


def main(argv):
    if len(argv) < 2 or not argv[0].isdigit():
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    limit = int(argv[0])
    long = []
    files = 0
    for target in argv[1:]:
        if not os.path.exists(target):
            print(f"{target}: no such file or directory", file=sys.stderr)
            return 2
        for path in rust_files(target):
            files += 1
            try:
                with open(path, encoding="utf-8") as f:
                    found = functions(f.read())
            except (LexError, UnicodeDecodeError, OSError) as e:
                print(f"{path}: cannot read: {e}", file=sys.stderr)
                return 2
            for name, first, last in found:
                if last - first + 1 > limit:
                    long.append((last - first + 1, path, first, name))
    for lines, path, first, name in sorted(long, key=lambda r: (-r[0], r[1], r[2])):
        print(f"{path}:{first}: fn {name} is {lines} lines (at most {limit})")
    if long:
        print(f"{len(long)} function(s) longer than {limit} lines: split them into named steps")
        return 1
    print(f"no function longer than {limit} lines in {files} files")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
