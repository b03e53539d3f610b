"""The package's shape: one installed top-level package, layered imports, a torch-free core.

The folders baselines/ and training/ install as `agent_envs.baselines` and
`agent_envs.training` (setuptools `package-dir`). import-linter's graph builder walks the
folder of the root package, so it cannot see those two in the source tree: the contract is
checked on a copy laid out as the installed wheel is.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parents[1]
MAPPED = {"agent_envs.baselines": "baselines", "agent_envs.training": "training"}


def _pyproject() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as fh:
        return tomllib.load(fh)


def _installed_layout(dest: Path) -> Path:
    """Copy the packages into dest as the wheel lays them out; return dest."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "agent_envs", dest / "agent_envs", ignore=ignore)
    for name, folder in MAPPED.items():
        shutil.copytree(ROOT / folder, dest / Path(*name.split(".")), ignore=ignore)
    return dest


def test_package_dir_maps_the_folders():
    setup = _pyproject()["tool"]["setuptools"]
    assert setup["package-dir"] == MAPPED


def test_every_package_folder_is_listed():
    """A new subpackage must be added to [tool.setuptools].packages or it is not installed."""
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    found = set()
    roots = {"agent_envs": ROOT / "agent_envs"} | {n: ROOT / f for n, f in MAPPED.items()}
    for name, folder in roots.items():
        for init in folder.rglob("__init__.py"):
            rel = init.parent.relative_to(folder).parts
            found.add(".".join((name, *rel)))
    assert found == listed


def test_import_contract(tmp_path):
    """core <- baselines <- training and the contracts inside layers (pyproject's
    [tool.importlinter]), via lint-imports: every contract kept."""
    lint = shutil.which("lint-imports", path=os.path.dirname(sys.executable))
    if lint is None:
        pytest.skip("import-linter is not installed (it comes with the dev extra)")
    view = _installed_layout(tmp_path / "view")
    env = {**os.environ, "PYTHONPATH": str(view)}
    proc = subprocess.run(
        [lint, "--config", str(ROOT / "pyproject.toml")],
        cwd=view,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    contracts = len(_pyproject()["tool"]["importlinter"]["contracts"])
    assert f"{contracts} kept, 0 broken" in proc.stdout


def test_core_imports_no_torch_and_steps_the_env():
    """`import agent_envs` and a few env steps must not import torch (or SB3)."""
    code = (
        "import sys, gymnasium as gym, agent_envs\n"
        "from agent_envs import swarm_v0\n"
        "from agent_envs.baselines import TurnpikeController\n"
        "env = gym.make('agent_envs/Swarm-v0', n_agents=5, n_steps=3)\n"
        "obs, _ = env.reset(seed=0)\n"
        "ctrl = TurnpikeController(env)\n"
        "for _ in range(3):\n"
        "    obs, *_ = env.step(ctrl.predict(obs)[0])\n"
        "bad = sorted(m for m in ('torch', 'stable_baselines3', 'pandas') if m in sys.modules)\n"
        "assert not bad, bad\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr


def test_bare_layer_imports_are_banned():
    """ruff's banned-api rule rejects `import baselines` / `import training` in the repo."""
    banned = _pyproject()["tool"]["ruff"]["lint"]["flake8-tidy-imports"]["banned-api"]
    assert set(banned) == {"baselines", "training"}
    ruff = shutil.which("ruff", path=os.path.dirname(sys.executable)) or shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (it comes with the dev extra)")
    probe = "from baselines import TurnpikeController\nimport training.train\n"
    proc = subprocess.run(
        [
            ruff,
            "check",
            "--config",
            str(ROOT / "pyproject.toml"),
            "--select",
            "TID251",
            "--stdin-filename",
            "probe.py",
            "-",
        ],
        input=probe,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1
    assert proc.stdout.count("TID251") == 2, proc.stdout


def test_cli_builds_light_subcommands_without_torch():
    """The CLI imports a subcommand's modules only when it is chosen: the reproduction of the
    uncontrolled runs and `evaluate --help` need neither torch nor SB3."""
    code = (
        "import sys\n"
        "from agent_envs.training import cli\n"
        "for name in ('reproduce-uncontrolled', 'evaluate', 'report'):\n"
        "    cli.build_parser(name)\n"
        "import agent_envs.training.experiments.uncontrolled\n"
        "bad = sorted(m for m in ('torch', 'stable_baselines3') if m in sys.modules)\n"
        "assert not bad, bad\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr


#: The longest function the training layer may hold (issue 17: a function doing resume,
#: metadata, model, callbacks, learning and summary at once was 170 lines).
MAX_FUNCTION_LINES = 80


def test_no_function_of_the_training_layer_is_longer_than_80_lines():
    """Every function in training/ (definition to last line, docstring included) fits in
    `MAX_FUNCTION_LINES`: a longer one does several jobs and is split by job."""
    import ast

    too_long = []
    for path in sorted((ROOT / "training").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    too_long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines})")
    assert not too_long, too_long


def _imported_modules(path: Path) -> list[str]:
    """The modules `path` imports (every `import` and `from ... import`, nested ones too)."""
    import ast

    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.append(node.module)
    return found


def test_numba_is_imported_only_in_the_native_layer():
    """`numba` (and llvmlite, which it brings) is imported in `agent_envs.native` only: every
    compiled path loads through its one loader and switch (pyproject's packages: agent_envs,
    baselines/ and training/)."""
    native = ROOT / "agent_envs" / "native"
    outside = []
    for folder in ("agent_envs", *MAPPED.values()):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if native in path.parents:
                continue
            for name in _imported_modules(path):
                if name.split(".")[0] in ("numba", "llvmlite"):
                    outside.append(f"{path.relative_to(ROOT)}: {name}")
    assert not outside, outside
    # (the test itself sees the imports: the native modules do import numba)
    assert any("numba" in _imported_modules(path) for path in native.glob("*.py"))


def test_native_leaf_modules_import_nothing_above_them():
    """The numba modules of `agent_envs.native` import only numpy, numba/llvmlite, the standard
    library and each other; only the loader is imported by the rest of the package."""
    native = ROOT / "agent_envs" / "native"
    above = []
    for path in sorted(native.glob("*.py")):
        for name in _imported_modules(path):
            if name.startswith("agent_envs") and not name.startswith("agent_envs.native"):
                above.append(f"{path.relative_to(ROOT)}: {name}")
    assert not above, above
