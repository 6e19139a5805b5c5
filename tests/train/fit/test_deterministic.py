"""Training runs torch with deterministic algorithms only (the same seed gives the same bundle), restores the
caller's setting afterwards, and does not pay for importing torch's compiler to set that flag (1.6 s of every fit
and update, inside an update's time budget)."""

from __future__ import annotations

import subprocess
import sys

import pytest

torch = pytest.importorskip("torch")

from photon_fields.train.fit.loop import deterministic_torch  # noqa: E402


def test_deterministic_inside_and_the_callers_setting_restored() -> None:
    before = torch.are_deterministic_algorithms_enabled()
    try:
        for outer in (False, True):
            torch._C._set_deterministic_algorithms(outer, warn_only=False)
            with deterministic_torch():
                assert torch.are_deterministic_algorithms_enabled()
                assert not torch.is_deterministic_algorithms_warn_only_enabled()
            assert torch.are_deterministic_algorithms_enabled() is outer
    finally:
        torch._C._set_deterministic_algorithms(before, warn_only=False)


def test_setting_the_flag_does_not_import_the_compiler() -> None:
    code = ("import sys\nfrom photon_fields.train.fit.loop import deterministic_torch\n"
            "with deterministic_torch():\n    pass\n"
            "print(sorted(m for m in ('torch._inductor', 'torch._dynamo') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
