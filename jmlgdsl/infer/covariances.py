"""Kalman covariances shared between particles: a graph of the distinct covariances seen so far.

A Kalman covariance depends only on the mode history and on which outputs were measured, never on
the data values. Particles therefore hold an index into a table of distinct covariances (nodes),
and for each node, mode and observation mask the covariance work is done once and cached: the
Cholesky factor of the innovation covariance, the gain and the child node. Covariances whose
entries agree to a relative tolerance (each entry relative to its own variances) are one class,
and an engine's particles hold one node of each class (its representative), so once the Riccati
recursion has converged an engine's nodes stop growing and a step costs no covariance arithmetic
at all. The units of a fleet share one graph: a covariance any of them met is worked out once.
"""

from __future__ import annotations

import numpy as np

from . import kalman


class _Growing:
    """An array that grows along its first axis with amortised doubling."""

    def __init__(self, shape, dtype=float, fill=0):
        self.buffer = np.full((16,) + tuple(shape), fill, dtype=dtype)  # the storage, valid up to `size`
        self._fill = fill
        self.size = 0

    def extend(self, block):
        n = self.size + len(block)
        if n > len(self.buffer):
            bigger = np.full((2 * n,) + self.buffer.shape[1:], self._fill, dtype=self.buffer.dtype)
            bigger[:self.size] = self.buffer[:self.size]
            self.buffer = bigger
        self.buffer[self.size:n] = block
        self.size = n

    @property
    def data(self):
        return self.buffer[:self.size]


class _Rows:
    """Per (node, mode) results of one Kalman step under one observation mask, for nodes 0..done-1.

    The four pieces a particle needs are packed side by side in one row per (node, mode), so that
    gathering them for every particle is one indexing operation."""

    def __init__(self, K, m, nx, complete):
        self.shapes = ((m, m), (), (m, nx), (nx, nx))  # Linv, logdet, gain_t, Sig_f
        sizes = [int(np.prod(shape)) for shape in self.shapes]
        self.bounds = [int(b) for b in np.cumsum([0] + sizes)]
        self.packed = _Growing((K, self.bounds[-1]))
        self.child = _Growing((K,), np.int64, -1)  # node of Sig_f, -1 until a particle needs it
        self.complete = complete  # every output measured

    def extend(self, Linv, logdet, gain_t, Sig_f):
        """Append the pieces of new nodes, each with leading axes (nodes, K)."""
        n, K = logdet.shape
        self.packed.extend(np.concatenate([a.reshape(n, K, -1) for a in (Linv, logdet, gain_t, Sig_f)], axis=2))
        self.child.extend(np.full((n, K), -1))

    def at(self, at):
        """(Linv, logdet, gain_t, Sig_f) at `at`: an array of nodes (every mode of each node in turn)
        or a (nodes, modes) pair of arrays (one entry per pair)."""
        rows = self.packed.buffer[at]
        return self.unpack(rows.reshape(-1, rows.shape[-1]))

    def unpack(self, rows):
        """(Linv, logdet, gain_t, Sig_f) of packed rows (..., J, width), as views."""
        (m, nx), (b1, b2, b3) = self.shapes[2], self.bounds[1:4]
        lead = rows.shape[:-1]
        return (rows[..., :b1].reshape(lead + (m, m)), rows[..., b1], rows[..., b2:b3].reshape(lead + (m, nx)),
                rows[..., b3:].reshape(lead + (nx, nx)))

    def Sig_f(self, node, mode):
        """Filtered covariances at (node, mode) pairs."""
        return self.at((node, mode))[3]


class CovarianceGraph:
    """Distinct covariances (nodes) and their cached per-mode Kalman steps, keyed by observation mask.

    A node is one covariance exactly (its bytes), so its pieces and its children are a pure function
    of it: the engines of a fleet's units share one graph (`shared`), and each gets the same bits
    whichever of them met a covariance first. Nodes whose entries agree to rtol are one class; an
    engine keeps the first node of each class it meets as the class's representative
    (`Representatives`) and holds only representatives, as a graph of its own would.
    """

    def __init__(self, model, rtol=1e-10):
        self.model = model
        self.rtol = rtol
        self._Sig = _Growing((model.nx, model.nx))
        self.classes = _Growing((), np.int64)  # each node's class
        self._nodes: dict[bytes, int] = {}  # a covariance's bytes -> its node
        self._keys_seen: dict[bytes, int] = {}  # a class's key -> the class
        self._rows: dict[bytes, _Rows] = {}
        self.shared = False  # engines of several units hold it: they compact it together (rbpf.share)

    @property
    def size(self) -> int:
        return self._Sig.size

    @property
    def Sig(self) -> np.ndarray:
        """Node covariances, (size, nx, nx)."""
        return self._Sig.data

    def _keys(self, Sigs):
        """Hashable keys equal for covariances whose entries agree to rtol relative to sqrt(Sig_ii Sig_jj).

        Each entry is rounded on its own grid, so a state with a small variance (another unit) keeps
        its relative precision instead of being rounded on the grid of the largest variance.
        """
        scale = np.frexp(np.abs(np.diagonal(Sigs, axis1=1, axis2=2)))[1]  # (n, nx) binary exponents
        grid = np.ldexp(self.rtol, (scale[:, :, None] + scale[:, None, :]) // 2)
        ticks = np.round(Sigs / grid).astype(np.int64).reshape(len(Sigs), -1)
        return [row.tobytes() for row in np.column_stack([scale.astype(np.int64), ticks])]

    def add(self, Sigs) -> np.ndarray:
        """Node indices for covariances (n, nx, nx), creating nodes for the values not met before."""
        out = np.empty(len(Sigs), dtype=np.int64)
        new = []
        for i, row in enumerate(np.ascontiguousarray(Sigs).reshape(len(Sigs), -1)):
            key = row.tobytes()
            node = self._nodes.get(key)
            if node is None:
                node = self._nodes[key] = self._Sig.size + len(new)
                new.append(i)
            out[i] = node
        if new:
            self._Sig.extend(Sigs[new])
            seen = self._keys_seen
            self.classes.extend([seen.setdefault(key, len(seen)) for key in self._keys(Sigs[new])])
        return out

    def rows(self, mask) -> _Rows:
        """Cached Kalman pieces for every node and mode under the observation mask (bool, ny)."""
        key = mask.tobytes()
        rows = self._rows.get(key)
        if rows is None:
            rows = self._rows[key] = _Rows(self.model.K, int(mask.sum()), self.model.nx, bool(mask.all()))
        done = rows.child.size
        if done < self.size:
            self._compute(rows, self.Sig[done:], mask)
        return rows

    def _compute(self, rows, Sig, mask):
        """Append the Kalman pieces of covariances Sig (n, nx, nx) under every mode to `rows`
        (the update of kalman.update, kept in factored form for reuse across particles)."""
        model = self.model
        rows.extend(*kalman.covariance_step(Sig[:, None], model.A, model.Q, model.C, model.R, mask))

    def children(self, rows: _Rows, node, mode) -> np.ndarray:
        """Nodes of the filtered covariances reached from `node` (n,) by `mode` (n,) under `rows`' mask."""
        child = rows.child.buffer[node, mode]
        missing = child < 0
        if missing.any():  # a pair met twice gets one node: `add` keeps equal covariances once
            new_node, new_mode = node[missing], mode[missing]
            rows.child.buffer[new_node, new_mode] = self.add(rows.Sig_f(new_node, new_mode))
            child = rows.child.buffer[node, mode]
        return child

    def compact(self, holders):
        """Keep only the nodes the holders (engines: `node`, their particles' nodes, and `reps`, their
        Representatives) use, renumbering them and their classes (dropping every cache)."""
        live = np.unique(np.concatenate([np.concatenate([h.node, h.reps.nodes()]) for h in holders]))
        renumbered = np.full(self.size, -1, dtype=np.int64)
        renumbered[live] = np.arange(len(live))
        Sig = self.Sig[live].copy()
        self._Sig = _Growing(Sig.shape[1:])
        self.classes = _Growing((), np.int64)
        self._nodes.clear()
        self._keys_seen.clear()
        self._rows.clear()
        self.add(Sig)
        for h in holders:
            h.node = renumbered[h.node]
            h.reps.renumber(self, renumbered)


class Representatives:
    """One engine's representative node of each class of covariances it has met: the first node of
    the class it met, as a graph of its own keeps the first covariance of each key. So its results
    do not depend on what other engines sharing the graph met, or in which order."""

    def __init__(self, graph, root):
        self.of = np.full(16, -1, dtype=np.int64)  # class -> its representative node, -1: not met
        self.held = 0  # the classes met: the size a graph of the engine's own would have
        self.pick(graph, root)

    def table(self, graph) -> np.ndarray:
        """The representative of every class of `graph`, -1 for those not met."""
        width = graph.classes.size
        if len(self.of) < width:
            self.of = np.concatenate([self.of, np.full(max(width, 2 * len(self.of)) - len(self.of), -1)])
        return self.of[:width]

    def pick(self, graph, nodes) -> np.ndarray:
        """The representatives of the classes of `nodes` (n,): a class met for the first time takes
        the first of its nodes in order."""
        rep = self.table(graph)[graph.classes.buffer[nodes]]
        if rep.min(initial=0) >= 0:  # every class met before (a converged graph: every step)
            return rep
        return Representatives.pick_together([self], graph, nodes, np.zeros(len(nodes), dtype=np.int64))

    @staticmethod
    def pick_together(each, graph, nodes, owner) -> np.ndarray:
        """`pick` of several engines' Representatives `each` side by side: node i is owner[i]'s."""
        classes = graph.classes.buffer[nodes]
        tables = [r.of for r in each]  # as they are where all are as long and long enough (every class in them)
        if len(set(map(len, tables))) > 1 or len(tables[0]) < graph.classes.size:
            tables = [r.table(graph) for r in each]
        rep = np.concatenate(tables).reshape(len(each), -1)[owner, classes]  # np.stack, without its steps per table
        missing = rep < 0
        if missing.any():  # new classes, taken in order: (engine, class) pairs, first occurrences
            pair = owner[missing] * graph.classes.size + classes[missing]
            new, first = np.unique(pair, return_index=True)
            for j, c, node in zip(new // graph.classes.size, new % graph.classes.size, nodes[missing][first]):
                each[j].of[c] = node
                each[j].held += 1
            rep[missing] = np.array([each[j].of[c] for j, c in zip(owner[missing], classes[missing])], dtype=np.int64)
        return rep

    def nodes(self) -> np.ndarray:
        """The representative nodes."""
        return self.of[self.of >= 0]

    def keep(self, graph, nodes):
        """Forget every class but those of `nodes`, as compacting a graph of the engine's own forgets
        the covariances its particles no longer hold."""
        live = np.unique(graph.classes.buffer[nodes])
        kept = self.of[live]
        self.of[:] = -1
        self.of[live] = kept
        self.held = len(live)

    def renumber(self, graph, renumbered):
        """Follow a move into `graph` (compacting, or joining another): the representatives as
        renumbered, each at its node's class there."""
        nodes = renumbered[self.nodes()]
        self.of = np.full(max(16, graph.classes.size), -1, dtype=np.int64)
        self.of[graph.classes.buffer[nodes]] = nodes
