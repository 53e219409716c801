"""Where each key of a TOML text starts: ``locate_keys(text) -> {key path: line}``, for error messages.

``tomllib`` gives values but no positions, so this scans the source text for the line where each key (and each
array element) starts. It computes no values; when it cannot place a key, the caller's message leaves the line out.
"""

from __future__ import annotations

import re
import tomllib

__all__ = ["locate_keys"]

class _Scanner:
    """A structural TOML scanner: it computes no values, only where each key and array element starts.

    It assumes the text already parsed with tomllib; on anything unexpected it stops, keeping what it found.
    """

    _BARE = re.compile(r"[A-Za-z0-9_-]+")

    def __init__(self, text: str):
        self.s = text
        self.n = len(text)
        self.i = 0
        self.line = 1
        self.loc: dict[tuple, int] = {}
        self.explicit: set[tuple] = set()
        self.aot: dict[tuple, int] = {}  # resolved path of an array of tables -> number of elements so far

    # -- positions
    def _advance_to(self, j: int) -> None:
        self.line += self.s.count("\n", self.i, j)
        self.i = j

    def _record(self, path: tuple, line: int, explicit: bool = True) -> None:
        if path not in self.loc or (explicit and path not in self.explicit):
            self.loc[path] = line
        if explicit:
            self.explicit.add(path)

    def _record_prefixes(self, path: tuple, line: int) -> None:
        for k in range(1, len(path)):
            self._record(path[:k], line, explicit=False)

    # -- lexing
    def _skip_ws(self) -> None:
        s, i = self.s, self.i
        while i < self.n and s[i] in " \t":
            i += 1
        self.i = i

    def _skip_ws_nl_comments(self) -> None:
        while self.i < self.n:
            c = self.s[self.i]
            if c in " \t\r":
                self.i += 1
            elif c == "\n":
                self.i += 1
                self.line += 1
            elif c == "#":
                j = self.s.find("\n", self.i)
                self.i = self.n if j < 0 else j
            else:
                return

    def _expect(self, token: str) -> None:
        if not self.s.startswith(token, self.i):
            raise ValueError(f"expected {token!r} at line {self.line}")
        self.i += len(token)

    def _key(self) -> tuple[str, ...]:
        parts = []
        while True:
            self._skip_ws()
            c = self.s[self.i] if self.i < self.n else ""
            if c == '"':
                start = self.i
                self._basic_string()
                parts.append(tomllib.loads("k = " + self.s[start:self.i])["k"])
            elif c == "'":
                j = self.s.index("'", self.i + 1)
                parts.append(self.s[self.i + 1:j])
                self.i = j + 1
            else:
                m = self._BARE.match(self.s, self.i)
                if not m:
                    raise ValueError(f"expected a key at line {self.line}")
                parts.append(m.group())
                self.i = m.end()
            self._skip_ws()
            if self.i < self.n and self.s[self.i] == ".":
                self.i += 1
                continue
            return tuple(parts)

    def _basic_string(self) -> None:
        s, i = self.s, self.i + 1
        while s[i] != '"':
            i += 2 if s[i] == "\\" else 1
        self._advance_to(i + 1)

    def _multiline(self, quote: str) -> None:
        s, i = self.s, self.i + 3
        while True:
            if quote == '"' and s[i] == "\\":
                i += 2
                continue
            if s.startswith(quote * 3, i):
                i += 3
                extra = 0
                while extra < 2 and i < self.n and s[i] == quote:  # up to two quotes may end the content
                    i += 1
                    extra += 1
                break
            i += 1
        self._advance_to(i)

    # -- grammar
    def _value(self, path: tuple) -> None:
        s = self.s
        if s.startswith('"""', self.i):
            self._multiline('"')
        elif s.startswith("'''", self.i):
            self._multiline("'")
        elif s[self.i] == '"':
            self._basic_string()
        elif s[self.i] == "'":
            self.i = s.index("'", self.i + 1) + 1
        elif s[self.i] == "[":
            self.i += 1
            k = 0
            while True:
                self._skip_ws_nl_comments()
                if s[self.i] == "]":
                    self.i += 1
                    return
                self._record(path + (k,), self.line)
                self._value(path + (k,))
                k += 1
                self._skip_ws_nl_comments()
                if s[self.i] == ",":
                    self.i += 1
        elif s[self.i] == "{":
            self.i += 1
            while True:
                self._skip_ws_nl_comments()
                if s[self.i] == "}":
                    self.i += 1
                    return
                self._keyval(path)
                self._skip_ws_nl_comments()
                if s[self.i] == ",":
                    self.i += 1
        else:
            m = re.compile(r"[^,\]}#\r\n]*").match(s, self.i)
            self.i = m.end()

    def _keyval(self, prefix: tuple) -> None:
        line = self.line
        path = prefix + self._key()
        self._record_prefixes(path, line)
        self._record(path, line)
        self._expect("=")
        self._skip_ws()
        self._value(path)

    def _resolve(self, key: tuple[str, ...]) -> tuple:
        """Insert the current element index after every array of tables the header key passes through."""
        out: tuple = ()
        for part in key:
            out = out + (part,)
            if out in self.aot:
                out = out + (self.aot[out] - 1,)
        return out

    def run(self) -> dict[tuple, int]:
        current: tuple = ()
        try:
            while True:
                self._skip_ws_nl_comments()
                if self.i >= self.n:
                    break
                line = self.line
                if self.s.startswith("[[", self.i):
                    self.i += 2
                    key = self._key()
                    self._expect("]]")
                    head = self._resolve(key[:-1]) + (key[-1],)
                    count = self.aot.get(head, 0)
                    self.aot[head] = count + 1
                    current = head + (count,)
                    self._record_prefixes(current, line)
                    self._record(head, line)
                    self._record(current, line)
                elif self.s[self.i] == "[":
                    self.i += 1
                    key = self._key()
                    self._expect("]")
                    current = self._resolve(key)
                    self._record_prefixes(current, line)
                    self._record(current, line)
                else:
                    self._keyval(current)
        except (ValueError, IndexError, tomllib.TOMLDecodeError):
            pass  # keep the positions found so far: a missing line is better than a wrong one
        return self.loc


def locate_keys(text: str) -> dict[tuple, int]:
    """Map each key path in the TOML ``text`` to the 1-based line where it starts.

    Paths are tuples of table keys (str) and array indices (int): ``("shading", "light", 0, "direction")``,
    ``("transfer", "opacity", 2)``. A table is placed at its header, or at the first key that creates it.
    """
    return _Scanner(text).run()
