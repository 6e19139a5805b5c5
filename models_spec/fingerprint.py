"""Scene fingerprints: what a photon map or a trained field was made for.

A fingerprint hashes exactly what determines the light distribution in the volume: the normalized
volume data (its own sha256, see ``runtime.scene.volume.Volume.fingerprint``), the transfer function and the
lights. It excludes the camera and the phase coefficient g, which a field is meant to vary over.

Beside the combined :func:`scene_fingerprint`, photon maps and bundles record one fingerprint per part
(:func:`fingerprint_parts`: ``volume``, ``transfer_function``, ``lights``), so that a mismatch can say
*what* differs (:func:`mismatch_detail`), e.g. "lights differ (volume and transfer function match)".
Files written before the parts were recorded have none; a mismatch then says the parts cannot be compared.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any

#: The parts of a scene fingerprint, in the order messages name them.
FINGERPRINT_PARTS: tuple[str, ...] = ("volume", "transfer_function", "lights")
_WORDS = {"volume": "volume", "transfer_function": "transfer function", "lights": "lights"}


def _canonical(obj: Any) -> Any:
    # Round floats so that a JSON round trip (repr of floats) cannot change the hash.
    if isinstance(obj, float):
        return float(f"{obj:.12g}")
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in sorted(obj.items())}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    return obj


def _sha256_json(obj: Any) -> str:
    return hashlib.sha256(json.dumps(_canonical(obj), sort_keys=True).encode()).hexdigest()


def _tf_without_name(transfer_function: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in transfer_function.items() if k != "name"}


def scene_fingerprint(volume_sha256: str, transfer_function: dict[str, Any], lights: list[dict[str, Any]]) -> str:
    """sha256 (hex) of the volume hash, the transfer function and the lights, canonically serialized.
    The transfer function's display name does not count."""
    return _sha256_json({"volume": volume_sha256, "tf": _tf_without_name(transfer_function), "lights": lights})


def fingerprint_parts(volume_sha256: str, transfer_function: Mapping[str, Any],
                      lights: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """One sha256 (hex) per part, keyed by :data:`FINGERPRINT_PARTS`: the volume's own hash, and the
    canonical hashes of the transfer function (without its name) and of the list of lights."""
    return {"volume": str(volume_sha256), "transfer_function": _sha256_json(_tf_without_name(transfer_function)),
            "lights": _sha256_json([dict(light) for light in lights])}


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def differing_parts(expected: Mapping[str, str] | None, recorded: Mapping[str, str] | None) -> list[str] | None:
    """The parts whose fingerprints differ, in :data:`FINGERPRINT_PARTS` order; None when either side has
    no per-part fingerprints (they cannot be compared)."""
    if not expected or not recorded:
        return None
    return [p for p in FINGERPRINT_PARTS if expected.get(p) != recorded.get(p)]


def mismatch_detail(expected: Mapping[str, str] | None, recorded: Mapping[str, str] | None) -> str:
    """What differs between two scenes' fingerprints, for a one-line message, e.g. ``"lights differ (volume
    and transfer function match)"``; without parts on either side, says that they cannot be compared."""
    diff = differing_parts(expected, recorded)
    if diff is None:
        if not recorded:
            return ("volume, transfer function or lights differ (which cannot be told: the file records no "
                    "per-part fingerprints)")
        return "volume, transfer function or lights differ (not compared part by part)"
    if not diff:  # only with an edited or corrupt file: every part equal, the combined hash not
        return "the fingerprints are inconsistent (every part matches but the combined fingerprint does not)"
    words = [_WORDS[p] for p in diff]
    same = [_WORDS[p] for p in FINGERPRINT_PARTS if p not in diff]
    verb = "differ" if len(diff) > 1 or diff == ["lights"] else "differs"
    text = f"{_join(words)} {verb}"
    if same:
        text += f" ({_join(same)} {'match' if len(same) > 1 or same == ['lights'] else 'matches'})"
    return text
