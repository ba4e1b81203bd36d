"""Topology of a triangle mesh file, counted from the file alone (read by meshio, an independent reader):
vertices as the file shares them by index, edges, boundary and non-manifold edges, edges whose two triangles run the
same way (inconsistent orientation), connected components and the Euler characteristic. A closed, consistently
oriented 2-manifold has no boundary, non-manifold or inconsistent edges. Used by run.py's holes section."""
import numpy as np


def mesh_topology(path):
    import meshio  # Debian's python3-meshio

    mesh = meshio.read(path)
    faces = np.concatenate([c.data for c in mesh.cells if c.type == "triangle"]).astype(np.int64)
    # Vertices as the file shares them by index (no welding by position: two sheets that touch at a grid point
    # stay two), unused ones dropped.
    used, faces = np.unique(faces, return_inverse=True)
    faces = faces.reshape(-1, 3)
    # Directed edges; an undirected edge's uses and how many run each way.
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lo, hi = directed.min(axis=1), directed.max(axis=1)
    keys = lo * (len(used) + 1) + hi
    edges, inverse, uses = np.unique(keys, return_inverse=True, return_counts=True)
    forward = np.bincount(inverse, weights=(directed[:, 0] < directed[:, 1]), minlength=len(edges))
    inconsistent = int(np.count_nonzero((uses == 2) & (forward != 1)))
    # Components of the graph of the triangles' edges (SciPy comes with python3-skimage).
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(len(used),) * 2)
    components, _ = connected_components(graph, directed=False)
    return {"vertices": len(used), "edges": len(edges), "faces": len(faces),
            "boundary_edges": int(np.count_nonzero(uses == 1)),
            "nonmanifold_edges": int(np.count_nonzero(uses > 2)), "inconsistent_edges": inconsistent,
            "components": int(components), "euler": len(used) - len(edges) + len(faces)}
