"""Volume rendering's shared pieces, below every renderer: rays, samples, quadrature, compositing, meshes.

The scene renderer (``nsim.rendering``), the human field (``nsim.human``) and the surface export
(``nsim.export``) all build on these, so they live one layer below all three (they import only
``nsim.geometry``):

``nsim.volume.rays``
    World-frame rays (``Rays``), their ``[near, far]`` range, per-image pose refinement (``se3_exp``).
``nsim.volume.samples``
    ``RaySamples`` (intervals along rays with density and colour) and ``RenderOutput``.
``nsim.volume.quadrature``
    NeRF's volume-rendering quadrature (weights, expected and median depth) and the proposal losses.
``nsim.volume.compositing``
    Several fields' samples on the same rays, merged in depth order and rendered once.
``nsim.volume.density_mesh``
    A triangle mesh from a density field: lattice sampling, marching cubes, cleanup, colours.
"""
