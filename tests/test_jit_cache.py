"""The cache of compiled CasADi functions (cosim.identify._jit): compiled once, loaded after, pruned by use.

Real compilations with the system C compiler into a temporary cache folder.
"""

from __future__ import annotations

import os
import time

import casadi as ca

from cosim.identify import _jit
from cosim.plant import native


def _function(k: int) -> ca.Function:
    x = ca.SX.sym("x")
    return ca.Function(f"f{k}", [x], [x * (k + 1.0)])


def test_libraries_are_kept_then_the_least_recently_used_pruned(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(native, "MAX_LIBRARIES", 2)
    folder = tmp_path / "jit"
    first = _jit.compiled(_function(0), "f0")
    assert first is not None and float(first(3.0)) == 3.0
    (library0,) = folder.glob("f0_*.so")
    os.utime(library0, (time.time() - 100, time.time() - 100))
    _jit.compiled(_function(1), "f1")
    (library1,) = folder.glob("f1_*.so")
    os.utime(library1, (time.time() - 50, time.time() - 50))
    again = _jit.compiled(_function(0), "f0")   # loaded, not compiled: now the most recently used
    assert float(again(2.0)) == 2.0 and library0.stat().st_mtime > library1.stat().st_mtime
    _jit.compiled(_function(2), "f2")           # a third: the least recently used (f1) goes
    assert sorted(p.name.split("_")[0] for p in folder.glob("*.so")) == ["f0", "f2"]


def test_prune_keeps_the_newest(tmp_path):
    for k in range(5):
        path = tmp_path / f"lib{k}.so"
        path.write_bytes(b"")
        os.utime(path, (1000.0 + k, 1000.0 + k))
    removed = _jit.prune(tmp_path, 3)
    assert sorted(p.name for p in removed) == ["lib0.so", "lib1.so"]
    assert sorted(p.name for p in tmp_path.glob("*.so")) == ["lib2.so", "lib3.so", "lib4.so"]
    assert _jit.prune(tmp_path, 3) == []
    assert len(_jit.prune(tmp_path, 0)) == 3 and not list(tmp_path.glob("*.so"))

