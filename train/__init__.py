"""photon_fields.train: photon tracing (Alg. 1), the torch field and its fit, the bundle export, the
evaluation and the demo. Imports the runtime package first so its OpenMP default is in force before torch
loads (see :mod:`photon_fields.runtime`)."""

import photon_fields.runtime  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads libgomp)
