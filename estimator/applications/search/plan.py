"""The order of the looks: expected cost to find an object, Bayes' rule after a failed look, and the
exact (subsets) and greedy planners. Pure array code, tested on hand-built arrays.

Notation: K particles with normalised weights ``w (K,)``; L looks with detection probabilities
``d (L, K)`` (the probability that look ``l`` finds the object if particle ``k`` is the truth: the
particle's ray tests say whether the object is in view, the camera then misses it with the
configured miss probability); travel costs ``cost (L + 1, L)``: row ``L`` is from the camera's
present place, row ``i < L`` from look ``i``'s viewpoint, both including the fixed cost of a look.

Given the failed looks ``S``, the object is still unfound with probability
``Q(S) = sum_k w_k prod_{l in S} (1 - d_lk)`` (misses are independent given the particle, not
given a region: a look at one region may see particles of another, and this is exact). An order
``l_1 .. l_L`` costs ``sum_i cost(l_{i-1}, l_i) * Q({l_1 .. l_{i-1}})`` in expectation (a look is
paid only if the object was not found before it), which the planners minimise.
"""
from __future__ import annotations

import itertools

import numpy as np

EXACT_MAX_LOOKS = 8
"""Plans of at most this many looks are exact (dynamic programming over subsets, O(2^L L^2));
longer ones are greedy (see :func:`plan_order`)."""


def miss_products(d: np.ndarray) -> np.ndarray:
    """``(2^L, K)``: ``prod_{l in S} (1 - d_lk)`` for every subset ``S`` of the L looks (bit ``l``
    of the subset's index), from ``d (L, K)``."""
    L, K = d.shape
    out = np.ones((1 << L, K))
    for s in range(1, 1 << L):
        low = (s & -s).bit_length() - 1
        out[s] = out[s & (s - 1)] * (1.0 - d[low])
    return out


def expected_cost(order, d: np.ndarray, w: np.ndarray, cost: np.ndarray) -> float:
    """Expected cost of looking in ``order`` (indices into the L looks) until the object is found
    (or every look of the order failed): ``d (L, K)``, ``w (K,)``, ``cost (L + 1, L)``."""
    L = d.shape[0]
    alive = np.asarray(w, dtype=float).copy()  # w_k times the misses so far
    prev, total = L, 0.0
    for v in order:
        total += cost[prev, v] * alive.sum()
        alive = alive * (1.0 - d[v])
        prev = v
    return float(total)


def brute_force_order(d: np.ndarray, w: np.ndarray, cost: np.ndarray) -> tuple[list[int], float]:
    """The order of all L looks with the least expected cost, by trying every order (L! of them:
    the tests' reference)."""
    best, best_cost = None, np.inf
    for order in itertools.permutations(range(d.shape[0])):
        c = expected_cost(order, d, w, cost)
        if c < best_cost - 1e-12:
            best, best_cost = list(order), c
    return best or [], float(best_cost if best is not None else 0.0)


def exact_order(d: np.ndarray, w: np.ndarray, cost: np.ndarray) -> tuple[list[int], float]:
    """The optimal order of all L looks by dynamic programming over the subsets of looks done and
    the last look: ``f(S, last) = min_v Q(S) cost(last, v) + f(S + v, v)``."""
    L = d.shape[0]
    if L == 0:
        return [], 0.0
    q = miss_products(d) @ np.asarray(w, dtype=float)  # (2^L,) Q(S)
    full = (1 << L) - 1
    f = np.zeros((1 << L, L + 1))  # f[S, last]; last = L: the start (only with S empty)
    choice = np.full((1 << L, L + 1), -1, dtype=int)
    for s in range(full - 1, -1, -1):
        todo = [v for v in range(L) if not s >> v & 1]
        lasts = [L] if s == 0 else [v for v in range(L) if s >> v & 1]
        for last in lasts:
            vals = [q[s] * cost[last, v] + f[s | 1 << v, v] for v in todo]
            j = int(np.argmin(vals))
            f[s, last], choice[s, last] = vals[j], todo[j]
    order, s, last = [], 0, L
    while s != full:
        v = int(choice[s, last])
        order.append(v)
        s, last = s | 1 << v, v
    return order, float(f[0, L])


def greedy_order(d: np.ndarray, w: np.ndarray, cost: np.ndarray) -> tuple[list[int], float]:
    """Look next where the probability of finding the object, given the failed looks, per unit of
    cost from the present viewpoint is largest (optimal for independent misses without travel
    costs; a heuristic with them)."""
    L = d.shape[0]
    alive = np.asarray(w, dtype=float).copy()
    order, prev, left = [], L, list(range(L))
    while left:
        gain = np.array([alive @ d[v] for v in left]) / np.maximum([cost[prev, v] for v in left], 1e-12)
        v = left.pop(int(np.argmax(gain)))
        order.append(v)
        alive = alive * (1.0 - d[v])
        prev = v
    return order, expected_cost(order, d, w, cost)


def plan_order(d: np.ndarray, w: np.ndarray, cost: np.ndarray,
               exact_max: int = EXACT_MAX_LOOKS) -> tuple[list[int], float, str]:
    """The look order, its expected cost and the method (``"exact"`` for at most ``exact_max``
    looks, else ``"greedy"``)."""
    if d.shape[0] <= exact_max:
        return (*exact_order(d, w, cost), "exact")
    return (*greedy_order(d, w, cost), "greedy")


def bayes_after_miss(w: np.ndarray, d_look: np.ndarray) -> np.ndarray:
    """Normalised weights ``(K,)`` after a look with detection probabilities ``d_look (K,)`` failed:
    ``w_k (1 - d_k) / sum_j w_j (1 - d_j)`` (``w`` unchanged if the look could not fail)."""
    post = np.asarray(w, dtype=float) * (1.0 - np.asarray(d_look, dtype=float))
    total = post.sum()
    return post / total if total > 0 else np.asarray(w, dtype=float).copy()


def find_probabilities(order, d: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each look of ``order``: the probability that it finds the object given that the looks
    before it failed ``(n,)``, and the probability that it is the look that finds it ``(n,)``."""
    alive = np.asarray(w, dtype=float).copy()
    cond, first = [], []
    for v in order:
        q = alive.sum()
        hit = float(alive @ d[v])
        cond.append(hit / q if q > 0 else 0.0)
        first.append(hit)
        alive = alive * (1.0 - d[v])
    return np.array(cond), np.array(first)
