"""The path index the scene delegate files prims under (plugin/usd/path_index.py): subtree look-ups must find exactly
what is filed at or under a path, whatever was added and removed before, including sibling names that sort between
a path and its children ("/A-x", "/A0" beside "/A/B")."""

import random

from tessera.usd.path_index import PathIndex


def test_subtree_look_ups_match_a_brute_force_model():
    paths = ["/", "/A", "/A/B", "/A/B/C", "/A-x", "/A0", "/A/B0", "/AB", "/Z/Q", "/A/C", "/B", "/A/B/C/D"]
    model: dict[str, set] = {}
    index = PathIndex()
    rng = random.Random(1)
    for step in range(6000):
        path, item = rng.choice(paths), rng.randint(0, 3)
        if rng.random() < 0.6 or step < 100:  # bursts of adds too (the bulk sort), then mixed edits
            index.add(path, item)
            model.setdefault(path, set()).add(item)
        else:
            index.discard(path, item)
            if path in model:
                model[path].discard(item)
                if not model[path]:
                    del model[path]
        if step % 5 == 0:
            root = rng.choice(paths)
            expected = sorted(i for p, items in model.items() for i in items
                              if root == "/" or p == root or p.startswith(root + "/"))
            assert sorted(index.under(root)) == expected, (step, root)
            assert index.at(path) == model.get(path, set())
