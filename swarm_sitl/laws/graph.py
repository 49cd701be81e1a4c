"""The directed communication graph: leader is node 0, followers 1..n.

An edge ``(src, dst)`` means the information of ``src`` is available to ``dst`` (the paper's
``(src, dst) in E``), so ``d_{dst,src} > 0``. ``M = L + diag(d_10, ..., d_n0)``.
"""

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


class GraphError(ValueError):
    """The graph is not one the estimator can work on."""


@dataclass(frozen=True)
class Edge:
    src: int
    dst: int
    weight: float = 1.0


@dataclass(frozen=True)
class Graph:
    n_followers: int
    edges: tuple[Edge, ...]

    @staticmethod
    def from_edges(n_followers: int, edges: Iterable[Edge | tuple]) -> "Graph":
        """Build and validate: nodes in range, no self loops, no edge into the leader, no duplicates,
        positive weights, and a directed spanning tree rooted at the leader."""
        es: list[Edge] = []
        seen: set[tuple[int, int]] = set()
        for e in edges:
            edge = e if isinstance(e, Edge) else Edge(*e)
            for node in (edge.src, edge.dst):
                if not 0 <= node <= n_followers:
                    raise GraphError(f"edge {edge.src}->{edge.dst}: node {node} is not 0..{n_followers}")
            if edge.src == edge.dst:
                raise GraphError(f"edge {edge.src}->{edge.dst}: self loop")
            if edge.dst == 0:
                raise GraphError(f"edge {edge.src}->0: the leader (node 0) takes no input")
            if not edge.weight > 0:
                raise GraphError(f"edge {edge.src}->{edge.dst}: weight must be > 0, got {edge.weight}")
            if (edge.src, edge.dst) in seen:
                raise GraphError(f"edge {edge.src}->{edge.dst} is listed twice")
            seen.add((edge.src, edge.dst))
            es.append(edge)
        g = Graph(n_followers, tuple(es))
        missing = g.unreachable_followers()
        if missing:
            names = ", ".join(str(i) for i in missing)
            raise GraphError(
                f"no spanning tree rooted at the leader: node 0 cannot reach follower(s) {names}"
            )
        return g

    def in_neighbours(self, node: int) -> tuple[tuple[int, float], ...]:
        """``(src, weight)`` of every edge into ``node``, sorted by src."""
        return tuple(sorted((e.src, e.weight) for e in self.edges if e.dst == node))

    def out_neighbours(self, node: int) -> tuple[int, ...]:
        return tuple(sorted(e.dst for e in self.edges if e.src == node))

    def hops_from(self, node: int) -> dict[int, int]:
        """The fewest edges from ``node`` to each node it reaches (``node`` itself: 0)."""
        hops = {node: 0}
        frontier = [node]
        while frontier:
            nxt = []
            for s in frontier:
                for d in self.out_neighbours(s):
                    if d not in hops:
                        hops[d] = hops[s] + 1
                        nxt.append(d)
            frontier = nxt
        return hops

    def reached_from(self, node: int) -> set[int]:
        """``node`` and every node a directed path leads to from it: whose information depends
        on ``node``'s (every follower, from the leader)."""
        reached = {node}
        frontier = [node]
        while frontier:
            s = frontier.pop()
            for e in self.edges:
                if e.src == s and e.dst not in reached:
                    reached.add(e.dst)
                    frontier.append(e.dst)
        return reached

    def unreachable_followers(self) -> list[int]:
        reached = self.reached_from(0)
        return [i for i in range(1, self.n_followers + 1) if i not in reached]

    def adjacency_bar(self) -> np.ndarray:
        """``D_bar`` (n+1 x n+1): ``D_bar[dst, src] = weight``."""
        D = np.zeros((self.n_followers + 1, self.n_followers + 1))
        for e in self.edges:
            D[e.dst, e.src] = e.weight
        return D

    def M(self) -> np.ndarray:
        """``M = L + diag(d_0)`` of the follower graph (n x n)."""
        Db = self.adjacency_bar()
        D = Db[1:, 1:]
        d0 = Db[1:, 0]
        L = np.diag(D.sum(axis=1)) - D
        return L + np.diag(d0)

    def theta_paper(self) -> np.ndarray:
        """Lemma 2.1 as printed: ``Theta = diag(theta_i)`` with ``[1/theta_i] = M^{-1} 1``.

        This does NOT always make ``Xi`` positive definite (a weighted tree is a counterexample,
        tests/test_graph_and_gains.py); ``theta()`` falls back to Qu's construction when it fails.
        """
        M = self.M()
        return np.diag(1.0 / np.linalg.solve(M, np.ones(self.n_followers)))

    def theta_qu(self) -> np.ndarray:
        """Qu (2009): ``theta_i = p_i / q_i`` with ``p = M^{-T} 1``, ``q = M^{-1} 1``; Xi is always PD."""
        M = self.M()
        ones = np.ones(self.n_followers)
        return np.diag(np.linalg.solve(M.T, ones) / np.linalg.solve(M, ones))

    def theta(self) -> np.ndarray:
        """A diagonal ``Theta > 0`` with ``Xi = M^T Theta + Theta M`` positive definite: the paper's when
        it works, Qu's otherwise (Theorem 1's proof needs only these two properties)."""
        Th = self.theta_paper()
        return Th if _is_pd(self.M(), Th) else self.theta_qu()

    def theta_source(self) -> str:
        return (
            "paper: 1/theta = M^-1 1"
            if _is_pd(self.M(), self.theta_paper())
            else ("Qu: theta = (M^-T 1)/(M^-1 1); the paper's Theta leaves Xi indefinite on this graph")
        )

    def xi(self) -> np.ndarray:
        """Lemma 2.1: ``Xi = M^T Theta + Theta M`` (positive definite)."""
        M, Th = self.M(), self.theta()
        return M.T @ Th + Th @ M


def _is_pd(M: np.ndarray, Th: np.ndarray) -> bool:
    X = M.T @ Th + Th @ M
    return bool(np.linalg.eigvalsh(0.5 * (X + X.T)).min() > 0)
