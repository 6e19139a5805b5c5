"""photon_fields.runtime: scenes, transport, the reference renderers and the neural renderer (numpy, numba,
onnxruntime; never torch).

Importing the package sets the product's one OpenMP default, before numba (or torch, in training) loads an
OpenMP runtime: idle pool threads wait passively (``OMP_WAIT_POLICY=PASSIVE``). On 2 cores, torch's and
numba's pools spinning after every parallel region steal each other's core (a cpu-preset fit next to one
busy process ran 1.4x faster with passive waiting; the same speed on an idle machine). A user's own
setting wins. Entry points import this package (directly, or through ``photon_fields.train``) before
anything that loads OpenMP.
"""

import os

OMP_DEFAULTS = {"OMP_WAIT_POLICY": "PASSIVE"}
for _key, _value in OMP_DEFAULTS.items():
    os.environ.setdefault(_key, _value)
