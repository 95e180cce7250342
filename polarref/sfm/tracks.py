"""Stage 4: feature tracks from verified matches.

Keypoints are graph nodes, inlier matches edges; a track is a connected component (the
equivalence classes a union-find builds, computed here with scipy's connected components).
A component holding two or more keypoints of one image is inconsistent (some match in it is
wrong and we cannot tell which). Policy ``conflicts``: "drop" (default) removes the whole
component; "split" partitions it greedily by breadth-first search over its match edges from the
best-connected keypoint, admitting a keypoint only if its image is not in the growing track yet
(COLMAP's correspondence-graph triangulation behaves alike), then repeats on the rest; the
robust triangulation rejects observations that still do not fit. Both are counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


@dataclass
class Tracks:
    """Observations of all tracks, sorted by track.

    Attributes:
        track: (O,) track index of each observation, ascending.
        image: (O,) image index; keypoint: (O,) keypoint index in that image.
        start: (T + 1,) observations of track t are ``start[t]:start[t + 1]``.
        num_conflicting: components that held two keypoints of one image (split or dropped).
    """

    track: np.ndarray
    image: np.ndarray
    keypoint: np.ndarray
    start: np.ndarray
    num_conflicting: int = 0

    @property
    def num_tracks(self) -> int:
        return len(self.start) - 1


def build_tracks(num_keypoints: list[int], inliers: dict[tuple[int, int], np.ndarray],
                 min_length: int = 2, conflicts: str = "drop") -> Tracks:
    """Tracks from verified matches.

    Args:
        num_keypoints: keypoints per image (N,).
        inliers: {(i, j): (M, 2) keypoint index pairs} for verified pairs.
        min_length: shortest track kept.
        conflicts: "split" or "drop" (see the module docstring).
    """
    if conflicts not in ("split", "drop"):
        raise ValueError(f"conflicts must be 'split' or 'drop', got {conflicts!r}")
    offset = np.concatenate([[0], np.cumsum(num_keypoints)]).astype(np.int64)
    n_nodes = int(offset[-1])
    edges = [np.stack([offset[i] + m[:, 0], offset[j] + m[:, 1]], 1)
             for (i, j), m in inliers.items() if len(m)]
    e = np.concatenate(edges, 0) if edges else np.zeros((0, 2), np.int64)
    graph = coo_matrix((np.ones(len(e), np.int8), (e[:, 0], e[:, 1])), shape=(n_nodes, n_nodes))
    _, label = connected_components(graph, directed=False)
    node_image = np.repeat(np.arange(len(num_keypoints)), num_keypoints)
    size = np.bincount(label)
    nodes = np.flatnonzero(size[label] >= min_length)
    lab, img = label[nodes], node_image[nodes]
    order = np.lexsort((img, lab))
    nodes, lab, img = nodes[order], lab[order], img[order]
    dup = (lab[1:] == lab[:-1]) & (img[1:] == img[:-1])
    bad = np.unique(lab[1:][dup])
    keep = ~np.isin(lab, bad)
    extra_nodes, extra_lab = [], []
    if conflicts == "split" and len(bad):
        next_label = int(label.max()) + 1
        for k, sub in enumerate(_split_components(nodes[~keep], lab[~keep], e, node_image, min_length)):
            extra_nodes.append(sub)
            extra_lab.append(np.full(len(sub), next_label + k, np.int64))
    nodes, lab, img = nodes[keep], lab[keep], img[keep]
    if extra_nodes:
        nodes = np.concatenate([nodes] + extra_nodes)
        lab = np.concatenate([lab] + extra_lab)
        img = node_image[nodes]
        order = np.lexsort((img, lab))
        nodes, lab, img = nodes[order], lab[order], img[order]
    _, track = np.unique(lab, return_inverse=True)
    start = np.searchsorted(track, np.arange(track.max() + 2 if len(track) else 1))
    return Tracks(track=track.astype(np.int64), image=img.astype(np.int64),
                  keypoint=(nodes - offset[img]).astype(np.int64), start=start.astype(np.int64),
                  num_conflicting=int(len(bad)))


def _split_components(nodes: np.ndarray, lab: np.ndarray, edges: np.ndarray, node_image: np.ndarray,
                      min_length: int):
    """Yield the nodes of each image-unique sub-track of the conflicting components (greedy BFS)."""
    from collections import defaultdict, deque

    in_bad = set(nodes.tolist())
    adj: dict[int, list[int]] = defaultdict(list)
    for a, b in edges.tolist():
        if a in in_bad:
            adj[a].append(b)
            adj[b].append(a)
    for comp in np.unique(lab):
        members = sorted(nodes[lab == comp].tolist(), key=lambda n: (-len(adj[n]), n))
        free = set(members)
        for seed in members:
            if seed not in free:
                continue
            track, images = [seed], {int(node_image[seed])}
            free.discard(seed)
            queue = deque([seed])
            while queue:
                for nb in adj[queue.popleft()]:
                    if nb in free and int(node_image[nb]) not in images:
                        free.discard(nb)
                        images.add(int(node_image[nb]))
                        track.append(nb)
                        queue.append(nb)
            if len(track) >= min_length:
                yield np.array(sorted(track), np.int64)
