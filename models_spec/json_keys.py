"""The keys of a JSON object read from a file: unknown ones are refused (a typo must not silently fall back to a
default) and missing ones named, as one line of problem text.

The text only: the caller raises it with its own error class (the runtime's ``InputError``, the contract's
:class:`photon_fields.models_spec.npz_manifest.NpzError`), so that both say the same thing about the same keys.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any


def unknown_keys_problem(unknown: Sequence[str], allowed: Iterable[str]) -> str:
    """``unknown key 'densty_scale' (did you mean 'density_scale'?); allowed: 'density_scale', 'points'``."""
    allowed = sorted(allowed)
    names = ", ".join(repr(str(k)) for k in unknown)
    text = f"unknown key{'s' if len(unknown) > 1 else ''} {names}"
    guesses = [g for k in unknown for g in difflib.get_close_matches(str(k), allowed, n=1, cutoff=0.75)]
    if len(guesses) == len(unknown):
        text += f" (did you mean {', '.join(repr(g) for g in guesses)}?)"
    return f"{text}; allowed: {', '.join(repr(k) for k in allowed)}"


def keys_problem(d: Mapping[str, Any], allowed: Iterable[str], required: Iterable[str] = ()) -> str | None:
    """What is wrong with the keys of ``d``: keys outside ``allowed`` first, then keys of ``required`` it lacks;
    None when nothing is."""
    allowed = set(allowed)
    unknown = [k for k in d if k not in allowed]
    if unknown:
        return unknown_keys_problem(unknown, allowed)
    missing = [k for k in required if k not in d]
    if missing:
        return f"missing {', '.join(repr(k) for k in missing)}"
    return None
