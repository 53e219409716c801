"""Bounds checked before anything grows: a scene's size and nesting before TOML parses it, and the counts that
allocate (views, frames) before the list of them is made.

``tomllib`` parses nested arrays and inline tables by recursion: a scene of 5,000 nested ``[`` ended in a
``RecursionError`` traceback. :func:`check_toml_text` scans the text once, outside strings and comments, and
refuses a file larger than :data:`MAX_SCENE_BYTES` or nested deeper than :data:`MAX_TOML_DEPTH` with one line
naming the line where it happens.

>>> check_toml_text("s.toml", "a = [[1, 2], {b = '[[['}]  # [[[[")
>>> check_toml_text("s.toml", "a = " + "[" * 40 + "]" * 40)
Traceback (most recent call last):
...
isplat.errors.IsplatError: s.toml:1: arrays and inline tables nested 33 deep; a scene nests at most 32
"""

from __future__ import annotations

from .errors import IsplatError

MAX_SCENE_BYTES = 16 << 20         # a scene is a few kilobytes; a colour map of thousands of points still fits
MAX_TOML_DEPTH = 32                # the deepest scene key nests 3 ([views] path = [{target = [x, y, z]}])
MAX_VIEWS = 100_000                # views (orbit steps, path frames) in one batch


def check_toml_text(name: str, text: str, max_bytes: int = MAX_SCENE_BYTES, max_depth: int = MAX_TOML_DEPTH) -> None:
    """Refuse TOML ``text`` larger than ``max_bytes`` (UTF-8) or with arrays / inline tables nested deeper than
    ``max_depth``, before it is parsed (one line naming ``name`` and the line)."""
    if len(text) > max_bytes or len(text.encode("utf-8", "surrogatepass")) > max_bytes:
        raise IsplatError(f"{name}: {len(text.encode('utf-8', 'surrogatepass'))} bytes; a scene has at most "
                          f"{max_bytes}")
    depth, line, i, n = 0, 1, 0, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
        elif c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif c in "\"'":
            triple = text.startswith(c * 3, i)
            quote = c * 3 if triple else c
            j = i + len(quote)
            while j < n:
                if c == '"' and text[j] == "\\":
                    j += 2
                    continue
                if text.startswith(quote, j):
                    j += len(quote)
                    while triple and j < n and text[j] == c:      # up to two more quotes end a triple string
                        j += 1
                    break
                if not triple and text[j] == "\n":
                    break                                         # tomllib reports the unterminated string
                j += 1
            line += text.count("\n", i, j)
            i = j
            continue
        elif c in "[{":
            depth += 1
            if depth > max_depth:
                raise IsplatError(f"{name}:{line}: arrays and inline tables nested {depth} deep; a scene nests at "
                                  f"most {max_depth}")
        elif c in "]}":
            depth = max(0, depth - 1)
        i += 1


def check_scene_text(name: str, text: str, overrides=()) -> None:
    """:func:`check_toml_text` for a scene file's text and each of its ``--set key=value``."""
    check_toml_text(name, text)
    for arg in overrides:
        if isinstance(arg, str):
            check_toml_text(f"--set {arg[:60]}{'...' if len(arg) > 60 else ''}", arg)


def check_count(what: str, n, limit: int = MAX_VIEWS) -> int:
    """Refuse a count that allocates (views, frames) above ``limit`` before anything is made for it."""
    if int(n) > limit:
        raise IsplatError(f"{what} = {n}: at most {limit} (each view is a frame rendered and kept)")
    return int(n)
