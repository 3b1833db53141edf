"""Minimum-cost spanning arborescence (Chu-Liu/Edmonds) on small dense graphs."""

from __future__ import annotations

from .abstraction import INF

Edge = tuple[int, int, int]  # (from, to, cost)


def min_arborescence(nodes: int, root: int, edges: list[Edge]) -> int:
    """The least total cost of edges reaching every node from `root` along a tree; INF if none exists."""
    total = 0
    while True:
        cheapest = [INF] * nodes
        parent = [-1] * nodes
        for u, v, w in edges:
            if u != v and w < cheapest[v]:
                cheapest[v] = w
                parent[v] = u
        for v in range(nodes):
            if v != root and cheapest[v] >= INF:
                return INF
        cheapest[root] = 0
        component = [-1] * nodes
        visited = [-1] * nodes
        count = 0
        for v in range(nodes):
            total += cheapest[v]
            x = v
            while visited[x] != v and component[x] == -1 and x != root:
                visited[x] = v
                x = parent[x]
            if x != root and component[x] == -1:  # a cycle through x: contract it
                u = parent[x]
                while u != x:
                    component[u] = count
                    u = parent[u]
                component[x] = count
                count += 1
        if count == 0:
            return total
        for v in range(nodes):
            if component[v] == -1:
                component[v] = count
                count += 1
        edges = [(component[u], component[v], w - cheapest[v]) for u, v, w in edges if component[u] != component[v]]
        nodes = count
        root = component[root]
