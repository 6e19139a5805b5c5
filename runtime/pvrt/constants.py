"""Defaults and limits of the PVRT pipeline, in one place (each with the reason for its value)."""

from __future__ import annotations

from photon_fields.models_spec.pvrt_transfer import PVRT_PARTS

#: Lighting basis kinds: the paper's DSF (Sec. 5) and SH, the comparison it makes (Sec. 6.1, Fig. 11).
BASIS_KINDS: tuple[str, ...] = ("dsf", "sh")
#: DSF order = icosahedral subdivision level: 12, 42, 162, 642 directions (Sec. 5.2), each basis light a cone of
#: radius h (31.7 degrees at order 1, 15.9 at order 2). The paper uses 642 on a GPU. The basis blurs a directional
#: light over its cone, and on a thin medium the multiple scattering keeps the light's shadows: the path tracer under
#: order 1's reconstruction of the vortex's light differs from it by a relative L2 of 0.06-0.07 in L_i, under order
#: 2's by 0.04 (0.07 with the light behind), under order 3's by 0.035 (bench/README.md, PVRT). Order 2 with l_max 0
#: and a 48^3 grid holds ~110 MB before compression (its reachable cells); where order 2 would not fit the memory
#: budget at a 32^3 grid (l_max 2, the anisotropic scenes) the default is order 1 (``precompute.auto_dsf_order``).
DSF_ORDERS: tuple[int, int] = (0, 3)
DEFAULT_DSF_ORDER = 2
#: SH lighting order = l_max (so (l_max + 1)^2 basis lights); the paper's SH comparison uses up to l_max 25.
SH_ORDERS: tuple[int, int] = (0, 8)
DEFAULT_SH_ORDER = 3
#: The radiant-exitance SH band limit l_max (Sec. 6.1: 1st order for isotropic, 4-6th for anisotropic phase
#: functions). We store incident radiance and apply the HG phase at render time (its SH coefficients are g^l), so
#: by default the transfer keeps the least l_max whose first dropped band weighs at most EXITANCE_TOLERANCE = g^(l+1)
#: (``sh.auto_exitance_order``): l_max 2 for |g| <= 0.4 (a truncation of g^3 <= 6.4 %), 1 for |g| <= 0.25, and 0 for
#: an isotropic medium, whose phase function reads band 0 only (the other bands cost memory, CPCA capacity and
#: splatting time for nothing).
EXITANCE_ORDERS: tuple[int, int] = (0, 4)
EXITANCE_TOLERANCE = 0.4**3
#: Transfer grid: cells along the volume box's longest side. The multiple scattering it holds varies over a few
#: voxels on thin media (the vortex's L_i error falls from 0.12 to 0.09 from 32 to 48 cells at 48^3 voxels); the
#: direct term of a directional light comes from the light volume (NEE) at render time. By default the grid is the
#: largest up to DEFAULT_GRID whose uncompressed transfer (the cells photons can reach x basis lights x parts x SH
#: coefficients float32) fits TRANSFER_BUDGET_BYTES (``precompute.auto_grid``): 48 on the embedded scenes. A budget
#: of 512 MB let the anisotropic ones take DSF order 2 at a 33^3 grid: head no better (PVRT / field 1.22-1.82), its
#: precomputation 118 s and +3.2 GB (bench/README.md, PVRT).
DEFAULT_GRID = 48
TRANSFER_BUDGET_BYTES = 384 << 20
#: The least default grid for which the default DSF order is kept (``precompute.auto_dsf_order``): below it the next
#: coarser order's finer grid is taken (a dense medium's lit skin needs the cells).
MIN_AUTO_GRID = 32
GRID_RANGE: tuple[int, int] = (4, 128)
#: Photon paths traced per basis light (Sec. 8.3's NP, here per basis light rather than per boundary voxel).
#: 2^18: on the vortex the transfer's frozen photon noise at 2^16 was a large part of PVRT's L_i error; 2^18 at
#: order 2 precomputes in ~20 s there (bench/README.md, PVRT).
DEFAULT_PATHS_PER_BASIS = 1 << 18
MAX_BOUNCES = 16  # the path tracer's max_depth: paths of up to 16 scattering vertices
#: Splatting kernel radius h = c * cell edge (Eq. 14; the paper's c = 4 on a full-resolution grid). Our transfer
#: grid is already coarser than the volume (2 voxels a cell at 96^3), so c = 1.5 cells is about the paper's
#: smoothing, at ~14 cells a photon.
KERNEL_C = 1.5
#: Where sigma_t times a cell's edge passes this, the splatting radius shrinks as KERNEL_C sqrt(tau / (sigma_t cell))
#: down to 1 cell (``precompute.splat_radius``): head's skull (~4 optical depths a cell) splats within ~1 cell, the
#: vortex's wisps and blobs (~1-1.4) at 1.5. A fixed 1.0 helped head (rel. L2 of L at 90 / 225 degrees 0.209 / 0.163
#: -> 0.189 / 0.151) and hurt blobs (0.137 / 0.134 at 45 / 135 -> 0.145 / 0.142); this rule gives head 0.190 / 0.148
#: and leaves blobs and the vortex as they were (bench/README.md, PVRT).
KERNEL_DENSE_TAU = 2.0
#: Quadrature points per voxel along each axis for the transfer's denominators D_v (runtime/pvrt/precompute.py).
#: sigma_t is the transfer function of the trilinear scalar, so a steep ramp concentrates it near the voxel centres,
#: and a midpoint rule of a few points per voxel aliases with them, the sign alternating with the parity: D_v, which
#: divides every value of the transfer, was several percent off with the 1-3 points the kernel alone needs, so the
#: transfer's bias depended on the volume's resolution and the grid. 8 keeps it within half a percent on the vortex
#: (bench/README.md, PVRT).
MASS_POINTS = 8
#: CPCA (Sec. 6.4): clusters and PCA bases per cluster. The paper uses 128 clusters / 4 bases for 512^3 voxels. At
#: order 2 and a 48^3 grid, 32 x 4 added 0.01-0.02 to the vortex's L_i error over the uncompressed transfer; 64 x 8
#: none (and smooths some photon noise away at 2^18 paths). The anisotropic scenes' longer matrices (l_max 2: 1512
#: floats a cell at order 1) need more bases: 64 x 16 took head's rel. L2 of L at 90 degrees from 0.190 to 0.179 and
#: blobs' at 135 from 0.136 to 0.125 (bench/README.md, PVRT).
DEFAULT_CLUSTERS = 64
DEFAULT_PCA_BASES = 16
KMEANS_ITERATIONS = 12
#: Light volume of a directional light's direct term (NEE through the medium): cells along the longest side. On the
#: 48^3 vortex 64 cells read L_d 4-8 % high (trilinear transmittance across thin lit wisps), 128 cells 1-3 %, for a
#: 512^2 relit frame of ~36 ms instead of ~15 (bench/README.md, PVRT).
DEFAULT_LIGHT_GRID = 128
#: Step, in voxels, of the shadow rays of the basis lighting's optical-depth volumes (runtime/pvrt/direct.py; once
#: per transfer). sigma_t is a steep transfer function of the interpolated scalar, often narrower than a voxel, and
#: a midpoint rule of one voxel misses part of it: the direct term came out a few percent high (bench/README.md, PVRT).
DIRECT_STEP = 0.5
#: Transfer parts: the first collision (direct, single scattering; scalar, before the albedo) and the later ones
#: (multiple scattering; RGB, because the albedo of earlier vertices colours it).
PARTS = PVRT_PARTS
#: Quadrature points for projecting sky functions and for the DSF basis' solid angles.
SPHERE_QUADRATURE = 1 << 14
