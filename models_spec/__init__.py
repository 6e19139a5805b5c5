"""The versioned contract between training (train/) and the runtime (runtime/).

Everything both sides must agree on lives here, once: file-format names and versions, the default phase
set, the scene fingerprint, the field's input conventions and target encoding (Eq. 6 / 7), the field
bundle's layout and manifest schema (:mod:`photon_fields.models_spec.bundle`). This package
depends on nothing but numpy and the standard library, so the runtime can import it with torch absent.
"""

from photon_fields.models_spec.bundle import BUNDLE_FORMAT, BUNDLE_VERSION
from photon_fields.models_spec.encoding import (
    DEFAULT_PSI,
    FieldConfig,
    decode_radiance,
    direction_input,
    encode_radiance,
    normalize_position,
)
from photon_fields.models_spec.fingerprint import (
    FINGERPRINT_PARTS,
    fingerprint_parts,
    mismatch_detail,
    scene_fingerprint,
)
from photon_fields.models_spec.photon_map import (
    DEFAULT_MAP_PHASES,
    DEFAULT_PHASES,
    DEFAULT_PHOTONS,
    PAPER_PHASES,
    PHASE_BINS,
    PHASE_WINDOW,
    PHOTON_MAP_FORMAT,
    PHOTON_MAP_VERSION,
)

__all__ = ["scene_fingerprint", "fingerprint_parts", "mismatch_detail", "FINGERPRINT_PARTS",
           "DEFAULT_MAP_PHASES", "DEFAULT_PHASES", "DEFAULT_PHOTONS", "PAPER_PHASES", "PHASE_BINS", "PHASE_WINDOW",
           "PHOTON_MAP_FORMAT", "PHOTON_MAP_VERSION",
           "DEFAULT_PSI",
           "FieldConfig", "encode_radiance", "decode_radiance", "normalize_position", "direction_input",
           "BUNDLE_FORMAT", "BUNDLE_VERSION"]
