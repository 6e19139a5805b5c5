"""Photon-map file format (written by ``train.photons.tracing``, read by ``runtime.photons.photon_map``).

A photon map is one ``.npz`` file (loaded with ``allow_pickle=False``) holding:

=============  ============  ===========================================================================
array          dtype/shape   meaning
=============  ============  ===========================================================================
position       float32 (n,3) world-space collision point (photon's 2nd or later real collision)
direction      float32 (n,3) unit travel direction of the photon *arriving* at the collision
power          float32 (n,3) RGB power arriving at the collision [W], already divided by the number of
                             emitted photon paths and multiplied by |G| (each phase's photons form a
                             complete map on their own)
phase          uint8 (n,)    index into ``meta["phases"]`` (the g the photon scattered with)
light          uint8 (n,)    optional: index into ``meta["lights"]`` of the light that emitted the photon
bounce         uint8 (n,)    optional: the record's collision number along its path (2, 3, ...)
prev_scalar    float32 (n,)  optional: the volume's scalar (a categorical volume's label index) at the path's
                             previous collision
meta           uint8 (m,)    UTF-8 JSON metadata (below)
=============  ============  ===========================================================================

``light`` (2026-11-26, optional, without a version change; maps traced before it lack it, and a reader from before it
refuses the array, naming it): which light each record's path started from, so that the map, and a field trained
from it with one output per light (:attr:`photon_fields.models_spec.encoding.FieldConfig.light_channels`), can keep
the lights' contributions apart and rescale one light's power or colour among several. A map with it also records
``lights``, and has fewer than :data:`MAX_LIGHTS` of them.

``bounce`` and ``prev_scalar`` (2026-11-26, optional, together, without a version change): a path's records are
consecutive in the map with ``bounce`` 2, 3, ... (a new path starts at 2; a null record, ``record_floor`` below, repeats
the number of the collision after it), so that the albedo at every earlier
collision of a record's path can be looked up again (the first collision is not stored: ``prev_scalar`` of the
record at 2 holds its scalar). An edit of the transfer function's albedo alone then reweights every record's power
exactly instead of retracing (:mod:`photon_fields.runtime.photons.albedo_reweight`).

Metadata keys (:data:`PHOTON_MAP_META_KEYS`; a reader refuses any other key, naming it): ``format``
(= PHOTON_MAP_FORMAT), ``version`` (= PHOTON_MAP_VERSION), ``scene_fingerprint``, ``phases`` (the set G),
``emitted`` (photon paths traced), ``stored`` (records), ``per_phase`` (records per phase), ``seed``,
``max_bounces``, ``trace_seconds``, ``scene_name``, ``emitted_per_phase`` and ``scene_parts``: the
per-part fingerprints ``{"volume", "transfer_function", "lights"}`` (:func:`photon_fields.models_spec.fingerprint.
fingerprint_parts`), so that a map used for another scene can say what differs. ``scene_parts`` was added
without a version change: it is optional (maps traced before it lack it; their mismatches say the parts
cannot be compared), and readers of version 1 that predate it ignore metadata keys they do not use.
``lights`` (2026-11-26), also optional and without a version change: the scene's lights as its fingerprint hashes them
(``Scene.light_identities``), so that a map can answer for the same lights with their flux rescaled
(:mod:`photon_fields.runtime.scene.light_rescale`); a map without it is read as before (no rescale), and a reader
from before it refuses the key, naming it.
``record_floor`` (2026-11-27), optional and without a version change: the record floor q in [0, 1) the map was
traced with (:data:`RECORD_FLOOR`; absent: 0, records at real collisions only). With q > 0 the map also holds
records at null collisions (``position``, ``direction``, ``power``, ``bounce`` and ``prev_scalar`` those of the real
collision the record precedes), and a record at x weighs Phi / max(sigma_t(x), q majorant(x)) instead of
Phi / sigma_t(x) (:mod:`photon_fields.runtime.photons.photon_path`). A reader from before it refuses the key, naming
it: it would weigh the null records wrongly.
"""

from __future__ import annotations

from photon_fields.models_spec.npz_manifest import NpzManifestFormat

PHOTON_MAP_FORMAT = "photon-fields/photon-map"
PHOTON_MAP_VERSION = 1
#: The paper's phase set G (Sec. 3.2): "the best compromise between tracing and training speed and quality".
PAPER_PHASES: tuple[float, ...] = (-0.75, 0.0, 0.75)
#: Five phases: the paper's with the midpoints added. L_i depends on g far from linearly, and a field that has
#: seen three g values is 25-50 % off between them; with five it stays within ~15 % on the embedded scenes
#: (bench/README.md, ``bench_fidelity.py``). Also the tent nodes of a field trained from a kernel in g.
DEFAULT_PHASES: tuple[float, ...] = (-0.75, -0.375, 0.0, 0.375, 0.75)
#: Photon records a map holds by default: a million per phase of DEFAULT_PHASES, or ~128k per bin of PHASE_BINS
#: (a window of the kernel in g then holds ~640k). More photons per phase (or window) shrink the KNN ball at the
#: same K, and with it the density estimate's bias at dense surfaces.
DEFAULT_PHOTONS = 1_000_000 * len(DEFAULT_PHASES)
#: Narrow phase bins for a kernel in g (:mod:`photon_fields.runtime.photons.phase_window`): 39 bins 0.05 apart over
#: [-0.95, 0.95], so that the window of every g in [-0.8, 0.8] lies whole inside them. That range reaches past
#: DEFAULT_PHASES' [-0.75, 0.75] on purpose: a field is worst at the ends of the g range it is trained on (it is
#: held from one side only), and with bins over [-0.9, 0.9] the end was g = -0.75, where shell's field was 9 % dark
#: (docs/training.md, "The ends of the g range").
PHASE_BINS: tuple[float, ...] = tuple(round(-0.95 + 0.05 * i, 6) for i in range(39))
#: Half-width h of the triangular kernel in g over PHASE_BINS: a window holds 5 bins with weight, ~14 % of the
#: map's photons, about as many as one phase of a DEFAULT_PHASES map of the same size.
PHASE_WINDOW = 0.15
#: The phase set a map is traced with by default (``pfn-train trace``, :func:`trace_photons`): the narrow bins the
#: default ``cpu`` preset trains any g from. A map of DEFAULT_PHASES (or the paper's) trains with ``cpu-phases``.
DEFAULT_MAP_PHASES: tuple[float, ...] = PHASE_BINS
PHOTON_MAP_ARRAYS = {"position": ("float32", 3), "direction": ("float32", 3), "power": ("float32", 3),
                     "phase": ("uint8", 0)}
#: Arrays a map may hold besides :data:`PHOTON_MAP_ARRAYS` (dtype, width as there).
PHOTON_MAP_OPTIONAL_ARRAYS = {"light": ("uint8", 0), "bounce": ("uint8", 0), "prev_scalar": ("float32", 0)}
#: Lights a map can tell apart (its ``light`` array is uint8); a scene with more is traced without the array.
MAX_LIGHTS = 255
#: Photon tracing's record floor q (:mod:`photon_fields.runtime.photons.photon_path`): besides its real collisions a
#: photon is recorded at null collisions, so that a record is made with probability max(sigma_t / majorant, q) and
#: weighs at most Phi / (q majorant). 0: real collisions only (maps traced before 2026-11-27). The value was chosen by
#: the fields' mean L_i over g against the path tracer's (docs/training.md, "Records with a floor").
RECORD_FLOOR = 0.1
#: Metadata keys a photon map must have, and the ones it may have besides.
PHOTON_MAP_META_REQUIRED: tuple[str, ...] = ("format", "version", "scene_fingerprint", "phases", "emitted")
PHOTON_MAP_META_KEYS: tuple[str, ...] = (*PHOTON_MAP_META_REQUIRED, "stored", "per_phase", "seed", "max_bounces",
                                         "trace_seconds", "scene_name", "emitted_per_phase", "scene_parts",
                                         "lights", "record_floor")
#: The file layout above, and its reader (:mod:`photon_fields.models_spec.npz_manifest`).
PHOTON_MAP_NPZ = NpzManifestFormat(kind="photon map", format=PHOTON_MAP_FORMAT, version=PHOTON_MAP_VERSION,
                                   entry="meta", label="metadata", keys=PHOTON_MAP_META_KEYS,
                                   required=PHOTON_MAP_META_REQUIRED, arrays=tuple(PHOTON_MAP_ARRAYS),
                                   remedy="re-trace it", optional=tuple(PHOTON_MAP_OPTIONAL_ARRAYS))
