"""PVRT: precomputed photon mapping for real-time volume relighting (Zhang, Dong, Ma, TVCG 2013).

One concept per module:

- :mod:`.constants`: every default and limit of the pipeline, in one place.
- :mod:`.sh`: real spherical harmonics (Sec. 6.1, Eq. 9): the radiant-exitance basis, and the lighting basis the
  paper compares DSF with.
- :mod:`.dsf`: the discrete spherical function (Sec. 5, Eq. 7-8) on icosahedral directions: the lighting basis.
- :mod:`.basis`: one interface over both lighting bases: evaluation, projection of a directional light (Sec. 8.2)
  and of a sky function (Sec. 5.2 / 8.1), rotation (Sec. 5.1).
- :mod:`.lighting`: a scene's lights (directional, constant environment) and sky functions as basis coefficients.
- :mod:`.precompute`: basis-light photon tracing (Sec. 6.3.1-6.3.2) and photon splatting (Sec. 6.3.3, Eq. 14) into
  per-voxel transfer matrices (Eq. 15).
- :mod:`.cpca`: clustered PCA of the transfer matrices (Sec. 6.4, Eq. 16).
- :mod:`.transfer`: the compressed transfer in memory and its file (format: ``models_spec/pvrt_transfer.py``).
- :mod:`.radiance`: the radiance volume after a light change, with early evaluation in CPCA space (Sec. 7.2,
  Eq. 17-21), and the light volume of a directional light's direct term (the NEE fall-back).
- :mod:`.direct`: the direct term of the lighting the basis represents (Sec. 6.2): optical-depth volumes along
  quadrature directions, once per transfer, weighted by the lighting at every frame.

The renderer that ray-marches the radiance volume is ``runtime/renderers/pvrt.py`` (Sec. 7.3). Precomputation
needs no torch, so it lives in the runtime: the viewer and ``photon_fields.render`` can precompute without the
``train`` extra; ``pfn-train pvrt`` is its command line.
"""
