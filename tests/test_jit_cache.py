"""The cache of compiled CasADi functions (cosim.identify._jit): compiled once, loaded after, pruned by use.

Real compilations with the system C compiler into a temporary cache folder.
"""

from __future__ import annotations

import os
import time

import casadi as ca

from cosim.identify import _jit


def _function(k: int) -> ca.Function:
    x = ca.SX.sym("x")
    return ca.Function(f"f{k}", [x], [x * (k + 1.0)])


def test_libraries_are_kept_then_the_least_recently_used_pruned(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_jit, "MAX_LIBRARIES", 2)
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



def test_a_tiered_function_is_interpreted_until_its_steps_pay_for_compiling_it(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    function = _function(3)
    tier = _jit.Tiered(function, "f3", instructions=100)
    # the budget: the steps whose interpretation costs what a compilation of 100 instructions would
    want = (_jit.COMPILE_S + 100 * _jit.COMPILE_S_PER_INSTRUCTION) / (100 * _jit.INTERPRETED_S_PER_INSTRUCTION)
    assert tier.budget == want and 1e5 < want < 1e7
    half = int(want // 2)
    assert tier.pick(half) is function and tier.pick(half) is function   # still under the budget
    assert not list((tmp_path / "jit").glob("f3_*.so"))
    compiled = tier.pick(half)                                            # over it: compiled now, and kept
    assert compiled is not function and float(compiled(2.0)) == 8.0
    assert len(list((tmp_path / "jit").glob("f3_*.so"))) == 1
    assert tier.pick(1) is compiled
    # another process (here: another tier) finds the library and loads it at once
    assert _jit.Tiered(_function(3), "f3", instructions=100).pick(1) is not function


def test_the_steps_interpreted_count_across_processes(tmp_path, monkeypatch):
    """A structure each process runs a little is compiled once the runs of all of them pay for it."""
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_jit, "_pending", {})
    third = int(_jit.Tiered(_function(5), "f5", instructions=100).budget // 3) + 1
    for process in range(3):
        function = _function(5)
        tier = _jit.Tiered(function, "f5", instructions=100)
        assert tier.steps == process * third                      # what the earlier processes ran
        picked = tier.pick(third)
        assert (picked is function) == (process < 2)
        _jit._remember()                                          # what a process does when it ends
    assert len(list((tmp_path / "jit").glob("f5_*.so"))) == 1 and not list((tmp_path / "jit").glob("*.steps"))


def test_without_a_compiler_a_tiered_function_stays_interpreted(tmp_path, monkeypatch):
    def no_compiler(cc):
        raise OSError("no C compiler")

    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_jit, "_compiler", no_compiler)
    function = _function(4)
    tier = _jit.Tiered(function, "f4", instructions=100)
    assert tier.pick(10 ** 9) is function and tier.pick(10 ** 9) is function
