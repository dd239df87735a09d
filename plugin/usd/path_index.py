"""Ids filed under USD prim paths, with subtree look-ups that touch only the subtree (no scan of every entry).

The scene delegate files each rprim and sprim under the prim it reads, so that an edit at a path finds what it
dirtied in time proportional to what lies under that path, whatever the size of the stage.
"""

from __future__ import annotations

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
    def __init__(self):
        self._ids: dict[str, set] = {}
        self._children: dict[str, set[str]] = {}

    def add(self, path: str, item) -> None:
        items = self._ids.get(path)
        if items is None:
            self._ids[path] = items = set()
            self._link(path)
        items.add(item)

    def discard(self, path: str, item) -> None:
        items = self._ids.get(path)
        if items is None:
            return
        items.discard(item)
        if not items:
            del self._ids[path]
            self._unlink(path)

    def at(self, path: str) -> set:
        return self._ids.get(path, set())

    def under(self, root: str) -> list:
        """Everything filed at `root` or below it."""
        found, pending = [], [root]
        while pending:
            path = pending.pop()
            found.extend(self._ids.get(path, ()))
            pending.extend(self._children.get(path, ()))
        return found

    def _link(self, path: str) -> None:
        while path != "/":
            parent = parent_path(path)
            children = self._children.setdefault(parent, set())
            if path in children:
                return
            children.add(path)
            path = parent

    def _unlink(self, path: str) -> None:
        # Drop the path, then every ancestor left with neither items nor children.
        while path != "/" and path not in self._ids and not self._children.get(path):
            self._children.pop(path, None)
            parent = parent_path(path)
            siblings = self._children.get(parent)
            if siblings is not None:
                siblings.discard(path)
            path = parent
