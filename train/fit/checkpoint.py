"""A run's checkpoint (``checkpoint.pt``): the field's weights, its config, the scene it was trained for.

``torch.save`` of a dict with exactly :data:`CHECKPOINT_KEYS`: format, version, ``state_dict``,
``field_config`` (:meth:`photon_fields.models_spec.encoding.FieldConfig.to_dict`), ``scene_fingerprint``,
``phases``, ``step`` (steps done) and ``summary``. Written atomically; read as strictly as the JSON files (no
pickled objects: ``weights_only``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from photon_fields.models_spec.encoding import FieldConfig
from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_path
from photon_fields.train.field.network import TorchPhotonField
from photon_fields.train.fit.settings import FitSettings

CHECKPOINT_FORMAT = "photon-fields/checkpoint"
CHECKPOINT_VERSION = 1
#: The keys of a checkpoint's dict (all written, all required when read).
CHECKPOINT_KEYS = ("format", "version", "state_dict", "field_config", "scene_fingerprint", "phases", "step", "summary")


def save_checkpoint(path: Path, model: TorchPhotonField, scene_fp: str, step: int,
                    summary: dict[str, Any]) -> None:
    """Write the field's weights, its config, the scene fingerprint and the run summary atomically."""
    payload = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "state_dict": model.state_dict(),
               "field_config": model.cfg.to_dict(), "scene_fingerprint": scene_fp,
               "phases": list(model.cfg.phases), "step": int(step), "summary": summary}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_checkpoint(path: str | Path,
                    expected_fingerprint: str | None = None) -> tuple[TorchPhotonField, dict[str, Any]]:
    """Rebuild the field of a ``checkpoint.pt`` (refusing another scene's with ``expected_fingerprint``).
    Its metadata is as strict as the JSON files: unknown or missing keys, a field config that does not
    parse or weights that do not fit it are one-line errors naming the file."""
    p = Path(path)
    try:
        data = torch.load(p, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError, EOFError) as exc:
        raise InputError(str(p), f"not a readable checkpoint: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise InputError(str(p), "not a photon-field checkpoint")
    if data.get("version") != CHECKPOINT_VERSION:
        raise InputError(str(p), f"checkpoint version {data.get('version')!r} is not supported")
    check_keys(data, CHECKPOINT_KEYS, str(p), required=CHECKPOINT_KEYS)
    if expected_fingerprint is not None and data.get("scene_fingerprint") != expected_fingerprint:
        raise InputError(str(p), "checkpoint was trained for another scene (fingerprint mismatch)")
    try:
        model = TorchPhotonField(FieldConfig.from_dict(data["field_config"]))
        model.load_state_dict(data["state_dict"])  # the surface input's grid included
    except (ValueError, TypeError, KeyError, RuntimeError) as exc:
        raise InputError(str(p), f"field_config or state_dict unusable: {' '.join(str(exc).split())[:300]}") from None
    return model, data


def finished_run(run_dir: str | Path, settings: FitSettings) -> dict[str, Any] | None:
    """The log of a finished fit in ``run_dir`` (status done, checkpoint present) made with exactly these
    settings, else None: lets benchmarks and the evaluation reuse a run instead of training it again."""
    run = Path(run_dir)
    try:
        log = json.loads((run / "log.json").read_text())
    except (OSError, ValueError):
        return None
    if log.get("status") != "done" or not (run / "checkpoint.pt").exists():
        return None
    return log if log.get("settings") == json.loads(json.dumps(settings.to_dict())) else None
