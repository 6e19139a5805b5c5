"""Everything a fit needs besides the scene and the map (:class:`FitSettings`), with its checks.

Defaults come from the :data:`photon_fields.train.fit.presets.DEFAULT_PRESET` preset, so the preset table is
the one source of them; :meth:`FitSettings.from_preset` starts from any other preset.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from photon_fields.models_spec.encoding import DEFAULT_PSI
from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.train.fit.loss import LOSSES
from photon_fields.train.fit.presets import DEFAULT_PRESET, PRESETS
from photon_fields.train.fit.schedule import KnnSchedule, default_schedule, naive_schedule
from photon_fields.train.fit.targets import G_SAMPLING_MODES, SAMPLING_MODES

_DEFAULT = PRESETS[DEFAULT_PRESET]
#: Settings a run's log may lack (added later; a run without them trained with their defaults' earlier meaning).
OPTIONAL_KEYS = ("per_light",)


@dataclass
class FitSettings:
    """Everything a fit needs besides the scene and the map (module docstring). Build it with
    :meth:`from_preset` for another preset than the default."""

    preset: str = DEFAULT_PRESET
    """Name of the preset the architecture comes from (:data:`photon_fields.train.fit.presets.PRESETS`)."""
    steps: int = _DEFAULT.steps
    """Training steps."""
    batch: int = _DEFAULT.batch
    """Samples per step."""
    lr: float = _DEFAULT.lr
    """Adam's learning rate before the decay."""
    lr_decay_start: float = _DEFAULT.lr_decay_start
    """Share of the steps after which the learning rate decays."""
    lr_decay_every: int = _DEFAULT.lr_decay_every
    """Steps between two x0.92 decays of the learning rate."""
    k: int = _DEFAULT.k
    """Photons per target estimate (Eq. 5's K)."""
    schedule: KnnSchedule | None = None
    """An explicit KNN radius schedule; None: from ``schedule_kind`` and the photon count."""
    schedule_kind: str = _DEFAULT.schedule
    """"staggered" (Table 1) or "naive" (its final radius throughout)."""
    sampling: str = _DEFAULT.sampling
    """Training positions: "box", "support" or "visible" (:mod:`photon_fields.train.fit.targets`)."""
    loss: str = _DEFAULT.loss
    """Training loss: "linear" or "log" (:mod:`photon_fields.train.fit.loss`)."""
    g_sampling: str = _DEFAULT.g_sampling
    """Training g: "discrete" (the phases), "continuous" or "mixed" (:mod:`photon_fields.train.fit.targets`)."""
    average: float = _DEFAULT.average
    """Share of the last steps whose parameters are averaged into the final field; 0: the last step's."""
    seed: int = 0
    """Seeds the model's initialization and the sampler: same seed, same field."""
    checkpoint_every: int = 500
    """Steps between checkpoints (and one at the end)."""
    val_points: int = 1 << 13
    """Held-out validation samples (in the support, at the final radius)."""
    val_every: int = 0
    """Steps between validations; 0: about 10 per run."""
    psi: float = DEFAULT_PSI
    """Eq. 6's precision of the encoded targets."""
    per_light: bool = True
    """Keep the lights apart: a field with one RGB output per light (``FieldConfig.light_channels``) when the scene
    has 2 to ``MAX_LIGHT_CHANNELS`` lights and the map records each photon's light, so that one light's power or
    colour can be edited among several without retraining; False (or one light): one output for all lights."""

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> FitSettings:
        """The settings of preset ``name`` with ``overrides`` (None values are ignored: "not given")."""
        if name not in PRESETS:
            raise InputError("--preset", f"unknown preset {name!r} (available: {', '.join(PRESETS)})")
        p = PRESETS[name]
        base = cls(preset=name, steps=p.steps, batch=p.batch, lr=p.lr, schedule_kind=p.schedule,
                   sampling=p.sampling, loss=p.loss, k=p.k, average=p.average, g_sampling=p.g_sampling,
                   lr_decay_start=p.lr_decay_start, lr_decay_every=p.lr_decay_every)
        return replace(base, **{k: v for k, v in overrides.items() if v is not None})

    def validate(self) -> None:
        """One-line InputError naming the option of any setting out of range."""
        if self.preset not in PRESETS:
            raise InputError("--preset", f"unknown preset {self.preset!r} (available: {', '.join(PRESETS)})")
        for name, v, lo, hi in (("--steps", self.steps, 1, 10**7), ("--batch", self.batch, 1, 1 << 22),
                                ("--k", self.k, 2, 1 << 16), ("--checkpoint-every", self.checkpoint_every, 1, 10**9),
                                ("learning-rate decay interval", self.lr_decay_every, 1, 10**7),
                                ("validation points", self.val_points, 1, 1 << 22)):
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise InputError(name, f"must be an integer in [{lo}, {hi}], got {v!r}")
        if not (math.isfinite(self.lr) and 0 < self.lr <= 10):
            raise InputError("--lr", f"must be in (0, 10], got {self.lr}")
        if not (isinstance(self.lr_decay_start, int | float) and 0.0 <= self.lr_decay_start <= 1.0):
            raise InputError("learning-rate decay start", f"must be in [0, 1] (a share of the steps), "
                             f"got {self.lr_decay_start!r}")
        if self.schedule_kind not in ("staggered", "naive"):
            raise InputError("--schedule", f"must be 'staggered' or 'naive', got {self.schedule_kind!r}")
        if not (isinstance(self.average, int | float) and 0.0 <= self.average < 1.0):
            raise InputError("--average", f"must be in [0, 1) (a share of the steps), got {self.average!r}")
        if self.loss not in LOSSES:
            raise InputError("--loss", f"must be one of {LOSSES}, got {self.loss!r}")
        if self.g_sampling not in G_SAMPLING_MODES:
            raise InputError("g_sampling", f"must be one of {G_SAMPLING_MODES}, got {self.g_sampling!r}")
        if self.sampling not in SAMPLING_MODES:
            raise InputError("--sampling", f"must be one of {SAMPLING_MODES}, got {self.sampling!r}")
        if not isinstance(self.per_light, bool):
            raise InputError("per_light", f"must be true or false, got {self.per_light!r}")
        if self.val_every < 0:
            raise InputError("validation interval", f"must be >= 0, got {self.val_every}")

    def resolve_schedule(self, photons: int) -> KnnSchedule:
        """The KNN schedule for a map of ``photons`` records."""
        if self.schedule is not None:
            return self.schedule
        staggered = default_schedule(photons)
        return staggered if self.schedule_kind == "staggered" else naive_schedule(staggered.radii_percent[-1])

    @classmethod
    def from_dict(cls, d: Any, what: str = "settings") -> FitSettings:
        """The settings :meth:`to_dict` wrote (a run's ``log.json``), validated; unknown or missing keys, and
        values of the wrong type or range, are one-line errors naming ``what``."""
        if not isinstance(d, dict):
            raise InputError(what, "must be an object")
        names = tuple(f.name for f in fields(cls))
        check_keys(d, names, what, required=tuple(n for n in names if n not in OPTIONAL_KEYS))
        values = dict(d)
        try:
            values["schedule"] = None if d["schedule"] is None else KnnSchedule.from_dict(d["schedule"])
            settings = cls(**values)
        except TypeError as exc:
            raise InputError(what, f"unusable ({exc})") from None
        try:
            settings.validate()
        except InputError as err:
            raise InputError(f"{what} {err.what}", err.problem) from None
        return settings

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings (recorded in log.json; :func:`finished_run` compares them)."""
        d = asdict(self)
        d["schedule"] = self.schedule.to_dict() if self.schedule is not None else None
        return d
