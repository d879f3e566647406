"""Surfaces out of a scene NeRF: a point cloud from the capture's rays and a mesh from the density.

Arrays in, arrays out (no files; ``nsim.io.mesh`` writes them, ``nsim.stages.export`` reads the
scene checkpoint and publishes). Everything stays in the scene's world frame: metres, z up
(``nsim.geometry.conventions``); nothing is re-centred or rescaled.

``nsim.export.points``
    Rays of the training cameras -> the surface each ray ends on (its median or expected depth
    where its opacity is high), the rendered colour there and the normal ``-grad sigma / |grad sigma|``
    (autograd of the density).
``nsim.export.extract`` with ``nsim.volume.density_mesh``
    The density on a lattice of nodes -> marching cubes at a density level -> faces kept where
    the cameras looked (optional) -> small components dropped -> vertex colours from short probe
    rays looking into the surface along its normal.
``nsim.export.preview``
    A labelled picture of both (top view, perspective view; axes in metres).
"""
