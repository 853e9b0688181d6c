"""A small Rust lexer for the repository's checks (tools/check_circles.py, tools/check_fn_len.py).

It knows just enough Rust to never mistake text for code: line and nested block comments (doc
comments included), string, byte-string and C-string literals with escapes, raw strings with any
number of `#`, character and byte literals (`'{'`, `'\\''`, `b'"'`, `'\\u{7d}'`) as opposed to
lifetimes and labels (`'a`, `'static`), raw identifiers (`r#type`) and `::`. Everything else is
one token per identifier, number or punctuation character, each with its 1-based line.
"""

import re
from typing import Iterator, NamedTuple

_RAW_STRING = re.compile(r'(?:b|c)?r(#*)"')
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NUMBER = re.compile(r"[0-9][0-9A-Za-z_]*(?:\.[0-9][0-9A-Za-z_]*)?")


class Token(NamedTuple):
    kind: str  # "ident", "punct", "str", "char", "num", "lifetime"
    text: str
    line: int


class LexError(Exception):
    pass


def tokens(src: str) -> Iterator[Token]:
    """The tokens of `src`, comments dropped. Raises LexError on an unterminated literal or
    comment (so a check never passes by reading half a file)."""
    i, n, line = 0, len(src), 1
    while i < n:
        c = src[i]
        if c == "\n":
            line += 1
            i += 1
        elif c.isspace():
            i += 1
        elif src.startswith("//", i):
            j = src.find("\n", i)
            i = n if j < 0 else j
        elif src.startswith("/*", i):
            depth, j = 1, i + 2
            while depth:
                if j >= n:
                    raise LexError(f"line {line}: unterminated block comment")
                if src.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif src.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            line += src.count("\n", i, j)
            i = j
        elif (m := _RAW_STRING.match(src, i)) and (i == 0 or not _is_ident_char(src[i - 1])):
            close = '"' + m.group(1)
            end = src.find(close, m.end())
            if end < 0:
                raise LexError(f"line {line}: unterminated raw string")
            j = end + len(close)
            yield Token("str", src[i:j], line)
            line += src.count("\n", i, j)
            i = j
        elif c == '"' or (c in "bc" and src.startswith('"', i + 1) and not _after_ident(src, i)):
            j = i + (1 if c == '"' else 2)
            while True:
                if j >= n:
                    raise LexError(f"line {line}: unterminated string")
                if src[j] == "\\":
                    j += 2
                elif src[j] == '"':
                    j += 1
                    break
                else:
                    j += 1
            yield Token("str", src[i:j], line)
            line += src.count("\n", i, j)
            i = j
        elif c == "'" or (c == "b" and src.startswith("'", i + 1) and not _after_ident(src, i)):
            k = i + (1 if c == "'" else 2)
            if k < n and src[k] == "\\":
                j = src.find("'", k + 2)
                if j < 0:
                    raise LexError(f"line {line}: unterminated character literal")
                yield Token("char", src[i : j + 1], line)
                i = j + 1
            elif k + 1 < n and src[k + 1] == "'" and src[k] != "\n":
                yield Token("char", src[i : k + 2], line)
                i = k + 2
            elif c == "'" and (m := _IDENT.match(src, k)):
                yield Token("lifetime", "'" + m.group(0), line)
                i = m.end()
            else:
                raise LexError(f"line {line}: stray quote")
        elif src.startswith("r#", i) and (m := _IDENT.match(src, i + 2)):
            yield Token("ident", m.group(0), line)
            i = m.end()
        elif m := _IDENT.match(src, i):
            yield Token("ident", m.group(0), line)
            i = m.end()
        elif m := _NUMBER.match(src, i):
            # `1..2` is a range, not the number `1.`: the pattern wants a digit after the dot.
            yield Token("num", m.group(0), line)
            i = m.end()
        elif src.startswith("::", i):
            yield Token("punct", "::", line)
            i += 2
        else:
            yield Token("punct", c, line)
            i += 1


def _is_ident_char(c: str) -> bool:
    return c.isalnum() or c == "_"


def _after_ident(src: str, i: int) -> bool:
    """Whether position `i` continues an identifier (so `ab"` is not a byte string)."""
    return i > 0 and _is_ident_char(src[i - 1])
