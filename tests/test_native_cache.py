"""numba's cache and the files the compiled Lanczos links in (agent_envs.native.lanczos).

numba keys a cached function on its own source file only, so an edit of lanczos_rule.py,
lanczos_tridiagonal.py or kernel.py would leave the compiled Lanczos on the old rule while the
numpy executor reads the new one. The module freezes a hash of those files into its cache
(`compiled_rule_stamp`); the loader refuses the compiled path where the two differ.
"""

from __future__ import annotations

import types

import pytest

from agent_envs import native

pytestmark = pytest.mark.skipif(
    not native.available("lanczos"), reason="needs numba (the compiled Lanczos)"
)


def test_the_cached_stamp_is_the_current_sources_hash():
    from agent_envs.native import lanczos

    assert lanczos.compiled_rule_stamp() == lanczos.RULE_STAMP


def test_a_stale_cache_keeps_the_compiled_lanczos_off(monkeypatch):
    from agent_envs.native import lanczos, loader

    # as if lanczos_rule.py had been edited after the cached machine code was compiled
    monkeypatch.setattr(lanczos, "RULE_STAMP", lanczos.RULE_STAMP ^ 1)
    with pytest.warns(RuntimeWarning, match="numba's cache"):
        assert loader._warm_up_lanczos(lanczos) is False
    monkeypatch.undo()
    assert loader._warm_up_lanczos(lanczos) is True


def test_the_stamp_follows_every_linked_file(tmp_path):
    from agent_envs.native.lanczos import _source_stamp

    files = []
    for name in ("rule", "tridiagonal", "kernel"):
        path = tmp_path / f"{name}.py"
        path.write_text(f"VALUE = '{name}'\n")
        files.append(types.SimpleNamespace(__file__=str(path)))
    before = _source_stamp(*files)
    assert before == _source_stamp(*files) and 0 <= before < 2**62
    for module in files:
        path = tmp_path / module.__file__
        text = path.read_text()
        path.write_text(text + "# edited\n")
        assert _source_stamp(*files) != before
        path.write_text(text)
        assert _source_stamp(*files) == before


def test_with_numba_every_compiled_path_serves():
    """Each path's load check compares its module with the numpy code it replaces and switches
    the path off where they differ; the tests that compare envs then compare numpy with numpy
    and still pass. So: with numba installed (CI installs it) and nothing switched off, every
    path must serve, or some check (or module) is wrong."""
    import os

    if os.environ.get("AGENT_ENVS_NUMBA", "1") == "0":
        pytest.skip("compiled paths switched off by AGENT_ENVS_NUMBA=0")
    assert native.status() == dict.fromkeys(native.PATHS, True)
