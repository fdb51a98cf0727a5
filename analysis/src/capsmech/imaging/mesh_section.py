"""The section of a triangulated closed surface by a coordinate plane: what a microscope
focused on the tube's mid-plane sees of a 3D capsule.

For a surface symmetric about the plane (the off-centre capsule of the 3D tube, offset along
x, is symmetric about y = 0) the section is also the outline of its projection on that plane:
on the plane the normal has no component across it, so the membrane is seen edge-on there,
as the dark line of a bright-field image. The 3D kernel writes half of it (``/profile``: x > 0,
the capsule's own axis); this gives the whole closed curve, both sides of the axis, which an
off-centre capsule needs.
"""
from __future__ import annotations

import numpy as np

from capsmech.errors import CapsmechError


class SectionError(CapsmechError, ValueError):
    """The plane does not cut the surface in one closed curve."""


def plane_section(nodes: np.ndarray, triangles: np.ndarray, normal_axis: int = 1, offset: float = 0.0
                  ) -> np.ndarray:
    """The closed curve where the plane ``x[normal_axis] = offset`` cuts the surface.

    Parameters
    ----------
    nodes : (n, 3) array
        Node positions.
    triangles : (m, 3) int array
        Node indices of each triangle (0-based), a closed surface.
    normal_axis : int
        The coordinate normal to the plane (0, 1 or 2).
    offset : float
        The plane's position along it.

    Returns
    -------
    (k, 2) array
        The section's points in order around the curve (not repeated at the end), in the
        plane's two other coordinates in cyclic order after ``normal_axis``, so (z, x) for
        the plane y = const: the tube axis first, as image coordinates are.

    Raises
    ------
    SectionError
        If the plane misses the surface or cuts it in more than one closed curve.
    """
    nodes = np.asarray(nodes, dtype=float)
    triangles = np.asarray(triangles, dtype=int)
    distance = nodes[:, normal_axis] - offset
    # A node exactly on the plane (symmetric meshes have many) would make segments of zero
    # length; treating it as on the positive side keeps every cut on an edge's interior or end.
    positive = distance >= 0.0
    cut = positive[triangles].sum(axis=1)
    crossing = triangles[(cut == 1) | (cut == 2)]
    if len(crossing) == 0:
        raise SectionError(f"the plane x[{normal_axis}] = {offset:g} misses the surface")
    # Each crossing triangle has two edges whose ends lie on opposite sides; the point on an
    # edge is shared by the two triangles of that edge, which links the segments into a curve.
    edges: list[tuple[int, int]] = []
    for tri in crossing:
        pairs = [(int(tri[k]), int(tri[(k + 1) % 3])) for k in range(3)]
        ends = [(min(pair), max(pair)) for pair in pairs]
        edges.extend(e for e in ends if positive[e[0]] != positive[e[1]])
    keys = {e: i for i, e in enumerate(dict.fromkeys(edges))}
    links = np.array([keys[e] for e in edges]).reshape(-1, 2)
    neighbours: dict[int, list[int]] = {}
    for a, b in links:
        neighbours.setdefault(int(a), []).append(int(b))
        neighbours.setdefault(int(b), []).append(int(a))
    if any(len(v) != 2 for v in neighbours.values()):
        raise SectionError("the section is not a set of closed curves (is the surface closed?)")
    order = [0]
    previous = -1
    while True:
        a, b = neighbours[order[-1]]
        step = b if a == previous else a
        if step == order[0]:
            break
        previous = order[-1]
        order.append(step)
    if len(order) != len(keys):
        raise SectionError(f"the plane x[{normal_axis}] = {offset:g} cuts the surface in more than one curve "
                           f"({len(order)} of {len(keys)} points on the first)")
    edge_list = list(keys)
    i, j = np.array([edge_list[k] for k in order]).T
    weight = distance[i] / (distance[i] - distance[j])
    points = nodes[i] + weight[:, None] * (nodes[j] - nodes[i])
    return points[:, [(normal_axis + 1) % 3, (normal_axis + 2) % 3]]
