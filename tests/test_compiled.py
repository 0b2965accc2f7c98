"""Numba's cache keyed on every kernel module's source (fem_impact/compiled.py): a kernel that calls another
module's must not load machine code compiled against that module's old source."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from fem_impact import compiled

PACKAGE = Path(compiled.__file__).parent


def test_every_module_with_kernels_takes_njit_from_compiled_and_is_keyed():
    users = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
             if re.search(r"^\s*(from numba import .*\bnjit\b|@(numba\.)?njit)", p.read_text(), re.M)}
    assert users - {"compiled.py"} == set(compiled.KERNELS)
    for name in compiled.KERNELS:
        text = (PACKAGE / name).read_text()
        assert "from ..compiled import njit" in text and not re.search(r"^from numba import .*\bnjit\b", text, re.M)


def test_the_cache_directory_changes_with_any_kernel_source(tmp_path):
    copies = []
    for name in compiled.KERNELS:
        copy = tmp_path / name.replace("/", "_")
        copy.write_bytes((PACKAGE / name).read_bytes())
        copies.append(copy)
    before = compiled.source_key(copies)
    assert compiled.source_key(copies) == before
    copies[0].write_text(copies[0].read_text() + "\n# changed\n")   # (cone.py: small_kernel.py calls it)
    assert compiled.source_key(copies) != before


def test_the_kernels_cache_goes_to_the_keyed_directory_unless_the_user_sets_one(tmp_path):
    code = ("import numba, fem_impact.nonsmooth.cone as c; from fem_impact import compiled; "
            "print(numba.config.CACHE_DIR); print(compiled.source_key(compiled.PACKAGE / k for k in compiled.KERNELS))")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True).stdout.split()
    assert out[0] == str(PACKAGE / "__pycache__" / "numba" / out[1])
    env["NUMBA_CACHE_DIR"] = str(tmp_path)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True).stdout.split()
    assert out[0] == str(tmp_path)


def test_warm_removes_only_the_caches_of_earlier_kernel_sources(tmp_path, monkeypatch):
    """fem_impact.app.warm.prune: the caches beside this version's go, this version's stays; a cache directory
    the user set (NUMBA_CACHE_DIR) is never touched."""
    import numba

    from fem_impact import compiled
    from fem_impact.app import warm

    root = tmp_path / "__pycache__" / "numba"
    current, old, other = root / "0123456789abcdef", root / "fedcba9876543210", root / "aaaaaaaaaaaaaaaa"
    monkeypatch.setattr(compiled, "PACKAGE", tmp_path)
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(current))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert warm.prune() == [] and not root.exists()   # (a fresh clone: no cache folder yet)
    for path in (current, old, other):
        path.mkdir(parents=True)
        (path / "kernel.nbi").write_text("x")
    mine = root / "notes"   # (a folder the program did not write: never removed)
    mine.mkdir()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(current))
    assert warm.prune() == [] and old.exists() and other.exists()
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert sorted(warm.prune()) == sorted([old, other])
    assert current.exists() and (current / "kernel.nbi").exists() and not old.exists() and not other.exists()
    assert mine.exists()
