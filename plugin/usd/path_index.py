"""Ids filed under USD prim paths, with subtree look-ups that touch only the subtree (no scan of every entry).

The scene delegate files each rprim and sprim under the prim it reads, so that an edit at a path finds what it
dirtied in time proportional to what lies under that path, whatever the size of the stage.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Iterator


def parent_path(path: str) -> str:
    return path.rsplit("/", 1)[0] or "/"


def ancestors(path: str) -> Iterator[str]:
    """Proper ancestors of a prim path, nearest first, ending with "/"."""
    while path != "/":
        path = parent_path(path)
        yield path


def is_at_or_under(path: str, root: str) -> bool:
    return root == "/" or path == root or path.startswith(root + "/")


class PathIndex:
    """Paths kept sorted: the paths under a root are a contiguous run, found by bisection (a path string sorts its
    descendants, those starting with "root/", between "root/" and "root0": "0" follows "/"). Adding is an append; the
    sort happens at the next look-up (one sort of 100 k paths, not 100 k tree insertions)."""

    def __init__(self):
        self._ids: dict[str, set] = {}
        self._sorted: list[str] = []    # paths that have (or had: dropped lazily) ids, sorted, no repeats
        self._unsorted: list[str] = []  # paths added since the last look-up
        self._dropped = 0               # entries of _sorted without ids

    def add(self, path: str, item) -> None:
        items = self._ids.get(path)
        if items is None:
            self._ids[path] = items = set()
            self._unsorted.append(path)
        items.add(item)

    def discard(self, path: str, item) -> None:
        items = self._ids.get(path)
        if items is None:
            return
        items.discard(item)
        if not items:
            del self._ids[path]
            self._dropped += 1

    def at(self, path: str) -> set:
        return self._ids.get(path, set())

    def under(self, root: str) -> list:
        """Everything filed at `root` or below it."""
        self._merge()
        if root == "/":
            paths = self._sorted
        else:
            paths = self._sorted[bisect_left(self._sorted, root + "/"):bisect_left(self._sorted, root + "0")]
            paths.append(root)
        found = []
        for path in paths:
            found.extend(self._ids.get(path, ()))
        return found

    def _merge(self) -> None:
        if self._dropped > 1024 and self._dropped * 2 > len(self._sorted):
            self._sorted = [path for path in self._sorted if path in self._ids]
            self._dropped = 0
        if not self._unsorted:
            return
        if len(self._unsorted) > 64:
            self._sorted = sorted(set(self._sorted).union(self._unsorted))
        else:
            for path in self._unsorted:
                at = bisect_left(self._sorted, path)
                if at == len(self._sorted) or self._sorted[at] != path:
                    self._sorted.insert(at, path)
                elif path in self._ids:
                    pass  # dropped once and filed again: the entry is still there
        self._unsorted.clear()
