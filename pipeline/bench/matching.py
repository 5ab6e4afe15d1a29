"""Greedy one-to-one matching of ground-truth rows to detected rows, shared by the analytics scores."""

from __future__ import annotations


def one_to_one(cands: list[tuple[int, int, int]]) -> list[tuple[int, int]]:
    """(truth row, event row) pairs from (distance, truth row, event row) candidates, nearest
    first, each row used at most once; the pairs sorted by truth row."""
    used_t: set[int] = set()
    used_e: set[int] = set()
    pairs = []
    for _, i, j in sorted(cands):
        if i not in used_t and j not in used_e:
            used_t.add(i)
            used_e.add(j)
            pairs.append((i, j))
    return sorted(pairs)
