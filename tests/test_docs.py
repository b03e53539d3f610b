"""The documentation: what a docs build alone would not catch, and the strict build itself.

- no absolute path of the machine a file was written on in `docs/`, the README or mkdocs.yml;
- every module of the package has its row in docs/ARCHITECTURE.md;
- the `SwarmEnv` docstring (the one written form of the env contract, rendered on the docs
  site) names every keyword argument the env accepts;
- every page in the nav exists and every page of docs/ is in the nav or excluded;
- the CLI reference, generated from the parser by docs/hooks/cli_reference.py, covers every
  subcommand;
- the Getting-started snippets run as written;
- the front page's animation stays small;
- `mkdocs build --strict` passes (skipped when the `docs` extra is not installed; CI installs
  it and also runs the build on its own).
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from scripts import load_script

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
# Where a machine's absolute paths show up: a project checkout, pytest's temp folders, homes.
ABSOLUTE_PATH = re.compile(r"(/work/|/tmp/pytest-|/root/|/home/[a-z]|/Users/[A-Za-z]|C:\\Users)")
TEXT_SUFFIXES = {".md", ".csv", ".json", ".yml", ".yaml", ".py", ".txt", ".html", ".toml"}


def _text_files():
    yield REPO / "README.md"
    yield REPO / "mkdocs.yml"
    for path in sorted(DOCS.rglob("*")):
        if path.is_file() and path.suffix in TEXT_SUFFIXES:
            yield path


def test_no_absolute_machine_paths_in_docs_and_readme():
    found = []
    for path in _text_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if ABSOLUTE_PATH.search(line):
                found.append(f"{path.relative_to(REPO)}:{number}: {line.strip()[:120]}")
    assert not found, "absolute machine paths (write them relative):\n" + "\n".join(found)


def _package_modules():
    for folder in ("agent_envs", "baselines", "training"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if path.name != "__init__.py":
                yield path


def test_architecture_has_a_row_for_every_module():
    text = (DOCS / "ARCHITECTURE.md").read_text()
    missing = [
        str(path.relative_to(REPO))
        for path in _package_modules()
        if not re.search(rf"[`/ ]{re.escape(path.name)}`", text)
    ]
    assert not missing, f"docs/ARCHITECTURE.md has no row for: {missing}"


def _documented_kwargs(doc: str) -> set[str]:
    section = doc.split("## Arguments", 1)[1].split("\n    ## ", 1)[0]
    names: set[str] = set()
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or set(cells[0]) <= {"-"} or cells[0] == "kwarg":
            continue
        first, *others = [n.strip() for n in cells[0].split(",")]
        names.add(first)
        # "epsilon_min, _max" names epsilon_max by its suffix
        names.update(first.rsplit("_", 1)[0] + n if n.startswith("_") else n for n in others)
    return names


def test_swarm_env_docstring_lists_every_keyword_argument():
    from agent_envs.envs.episode_config import ENV_OPTION_NAMES
    from agent_envs.envs.swarm_env import SwarmEnv
    from agent_envs.params import SwarmParams

    # the env's own arguments (render_mode, num_threads) and the episode's configuration
    own = set(inspect.signature(SwarmEnv.__init__).parameters) - {"self", "kwargs"}
    assert own == {"render_mode", "num_threads"}
    accepted = set(SwarmParams.field_names()) | own
    accepted |= set(ENV_OPTION_NAMES)
    assert _documented_kwargs(SwarmEnv.__doc__) == accepted


def test_env_docstrings_have_gymnasiums_sections():
    from agent_envs.envs.swarm_env import SwarmEnv
    from agent_envs.envs.swarm_parallel import SwarmParallelEnv

    sections = [
        "Description",
        "Action Space",
        "Observation Space",
        "Rewards",
        "Starting State",
        "Episode End",
        "Arguments",
        "Version History",
    ]
    for env in (SwarmEnv, SwarmParallelEnv):
        missing = [s for s in sections if f"## {s}" not in env.__doc__]
        assert not missing, f"{env.__name__}: no section {missing}"


def _nav_files(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, dict):
        return [f for value in node.values() for f in _nav_files(value)]
    return [f for item in node for f in _nav_files(item)]


def test_nav_pages_exist_and_every_page_is_in_the_nav():
    yaml = pytest.importorskip("yaml")

    class _Loader(yaml.SafeLoader):  # mkdocs.yml may hold !!python tags in other projects
        pass

    config = yaml.load((REPO / "mkdocs.yml").read_text(), Loader=_Loader)
    nav = _nav_files(config["nav"])
    assert [page for page in nav if not (DOCS / page).is_file()] == []
    excluded = config.get("exclude_docs", "").split()
    pages = [str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")]
    orphans = [p for p in pages if p not in nav and p not in excluded]
    assert orphans == [], f"pages in docs/ that the nav does not list: {orphans}"
    # every page opens with its title (after an optional marker comment and blank lines)
    untitled = [
        page
        for page in nav
        if not re.match(r"(<!--.*?-->\s*)?# ", (DOCS / page).read_text(), flags=re.S)
    ]
    assert untitled == [], f"pages whose first line is not a '# title': {untitled}"


def _cli_hook():
    return load_script(DOCS / "hooks" / "cli_reference.py")


def test_cli_reference_covers_every_subcommand():
    from agent_envs.training.commands.cli import SUBCOMMANDS

    hook = _cli_hook()
    text = hook.cli_reference_markdown()
    for name in SUBCOMMANDS:
        shown = "agent-envs " + name.replace("reproduce-", "reproduce ")
        assert f"## {shown}\n" in text
        assert f"usage: {shown}" in text
    assert text.count("usage: ") == len(SUBCOMMANDS) + 1
    assert "--preset" in text and "--seeds" in text
    assert not ABSOLUTE_PATH.search(text)
    page = (DOCS / "cli.md").read_text()
    assert hook.MARKER in page


def _snippets() -> list:
    text = (DOCS / "getting-started.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    params = []
    for i, block in enumerate(blocks):
        marks = [pytest.mark.slow] if "stable_baselines3" in block else []
        params.append(pytest.param(block, id=f"block{i}", marks=marks))
    return params


@pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning")
@pytest.mark.parametrize("block", _snippets())
def test_getting_started_snippet_runs(block, capsys):
    for module in ("torchrl", "stable_baselines3"):
        if f"from {module}" in block and importlib.util.find_spec(module) is None:
            pytest.skip(f"{module} is not installed (its optional extra)")
    exec(compile(block, "getting-started.md", "exec"), {"__name__": "__docs__"})


def test_front_page_animation_is_small():
    gif = DOCS / "figures" / "swarm_controllers.gif"
    assert gif.is_file() and gif.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    assert gif.stat().st_size < 2 * 2**20
    assert "figures/swarm_controllers.gif" in (DOCS / "index.md").read_text()


def test_mkdocs_build_strict(tmp_path):
    if (
        importlib.util.find_spec("mkdocs") is None
        or importlib.util.find_spec("mkdocstrings") is None
    ):
        pytest.skip('MkDocs or mkdocstrings is not installed (pip install -e ".[docs]")')
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        check=False,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    assert (tmp_path / "envs" / "gymnasium" / "index.html").is_file()
