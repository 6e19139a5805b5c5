"""Scene fingerprints: what a photon map or a trained field was made for.

A fingerprint hashes exactly what determines the light distribution in the volume: the normalized
volume data (its own sha256, see ``runtime.volume.Volume.fingerprint``), the transfer function and the
lights. It excludes the camera and the phase coefficient g, which a field is meant to vary over.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any


def _canonical(obj: Any) -> Any:
    # Round floats so that a JSON round trip (repr of floats) cannot change the hash.
    if isinstance(obj, float):
        return float(f"{obj:.12g}")
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in sorted(obj.items())}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    return obj


def scene_fingerprint(volume_sha256: str, transfer_function: dict[str, Any], lights: list[dict[str, Any]]) -> str:
    """sha256 (hex) of the volume hash, the transfer function and the lights, canonically serialized.
    The transfer function's display name does not count."""
    tf = {k: v for k, v in transfer_function.items() if k != "name"}
    payload = json.dumps(_canonical({"volume": volume_sha256, "tf": tf, "lights": lights}), sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()
