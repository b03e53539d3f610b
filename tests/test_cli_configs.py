"""One route from the command line to a config (issue 17): the seed-list parser, the options
dataclasses of every subcommand, and the options generated from them."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import pytest

from agent_envs.training.commands.cli import SUBCOMMANDS, build_parser
from agent_envs.training.commands.parser import add_dataclass_arguments
from agent_envs.training.defaults import DEFAULT_TEST_SEEDS, MAX_SEEDS, parse_seeds
from agent_envs.validation import MAX_SEED

# ------------------------------------------------------------------------------- seed lists


@pytest.mark.parametrize(
    ("items", "seeds"),
    [
        ("0,1,2", [0, 1, 2]),
        (["0", "1", "2"], [0, 1, 2]),
        (["0-2", "7", "10:12"], [0, 1, 2, 7, 10, 11]),
        ("0-2,7, 10:12", [0, 1, 2, 7, 10, 11]),
        ("5", [5]),
        ([3, 4], [3, 4]),
        (7, [7]),
        ("4294967294:4294967296", [MAX_SEED - 1, MAX_SEED]),
        ("2-2", [2]),
    ],
)
def test_parse_seeds_accepts_every_spelling_of_one_syntax(items, seeds):
    assert parse_seeds(items) == seeds


@pytest.mark.parametrize(
    ("items", "message"),
    [
        ("x", "'x' is not a seed"),
        ("-1", "is not a seed"),
        ("1.5", "is not a seed"),
        ("0..3", "A-B"),
        ("3-1", "empty"),
        ("5:5", "empty"),
        ("0,4294967296", "largest seed"),
        ("0:4294967297", "largest seed"),
        ("9" * 5000, "largest seed"),
        ("1,1", "twice: 1"),
        (["0-3", "2"], "twice: 2"),
        (f"0:{MAX_SEEDS + 1}", f"more than {MAX_SEEDS}"),
        ([], "no seed given (leave the option out for 10000-10019)"),
        (",", "no seed given"),
        ([-1], "[0, 4294967295]"),
    ],
)
def test_parse_seeds_names_the_option_and_the_syntax(items, message):
    with pytest.raises(ValueError, match="--test-seeds") as exc:
        parse_seeds(items, "--test-seeds")
    assert message in str(exc.value)


def test_parse_seeds_default_and_types():
    assert parse_seeds(None) == list(DEFAULT_TEST_SEEDS)
    assert parse_seeds(None, default=(0,)) == [0]
    assert parse_seeds(None, default=None) is None  # the caller's own default applies
    with pytest.raises(TypeError, match="--seeds"):
        parse_seeds([True])
    with pytest.raises(ValueError, match="leave the option out for 0"):
        parse_seeds([], default=(0,))


# -------------------------------------------------------------------- options from configs


def _subparser(name: str) -> argparse.ArgumentParser:
    parser = build_parser(name)
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices[name]


@pytest.mark.parametrize("name", sorted(SUBCOMMANDS))
def test_every_option_is_a_field_of_the_subcommands_config(name):
    """Each subcommand's options are exactly its dataclass's fields (one route)."""
    fields = {f.name for f in dataclasses.fields(SUBCOMMANDS[name].config_class()) if f.init}
    dests = {a.dest for a in _subparser(name)._actions if a.dest != "help"}
    assert dests == fields


def test_the_five_hand_written_parsers_keep_their_option_names():
    expected = {
        "reproduce-uncontrolled": {"--out", "--n-agents", "--n-paths", "--seed"},
        "reproduce-turnpike": {
            "--out", "--seeds", "--modes", "--n-agents", "--n-paths", "--n-steps",
            "--no-progress",
        },
        "reproduce-turnpike-property": {
            "--out", "--n-agents", "--n-paths", "--tau", "--horizons", "--sigmas",
            "--epsilons", "--kernels", "--delta", "--seed", "--n-seeds", "--starts",
            "--max-control", "--gtol", "--max-iterations", "--no-progress",
        },
        "evaluate": {
            "--policy", "-p", "--task", "--env-id", "--env-kwargs", "--seeds", "--target",
            "--beta", "--delta", "--out", "--report", "--no-progress",
        },
        "report": {"--out", "--title", "--reference", "--seed-index"},
    }  # fmt: skip
    for name, flags in expected.items():
        parser = _subparser(name)
        given = {s for a in parser._actions for s in a.option_strings} - {"-h", "--help"}
        assert given == flags, name
    positional = [a.dest for a in _subparser("report")._actions if not a.option_strings]
    assert positional == ["results"]


def test_namespace_becomes_the_validated_config(tmp_path):
    from agent_envs.training.commands.evaluate import EvaluateConfig
    from agent_envs.training.experiments.turnpike_controlled import TurnpikeReproductionConfig
    from agent_envs.training.experiments.turnpike_property import TurnpikePropertyConfig
    from agent_envs.training.results.report import ReportConfig

    def parse(name: str, argv: list[str]):
        command = SUBCOMMANDS[name]
        return command.options(build_parser(name).parse_args([name, *argv]))

    config = parse("evaluate", ["--out", str(tmp_path), "-p", "zero", "--seeds", "0-2", "5"])
    assert isinstance(config, EvaluateConfig)
    assert config.seeds == (0, 1, 2, 5) and config.policies == ("zero",)
    assert config.out == tmp_path and config.progress and not config.report
    assert config.policy_specs() == {"zero": "zero"}
    default = parse("evaluate", ["--out", "o", "--no-progress", "--report"])
    assert default.seeds == DEFAULT_TEST_SEEDS and not default.progress and default.report
    assert len(default.policy_specs()) == 3

    turnpike = parse("reproduce-turnpike", ["--seeds", "0,3", "--modes", "env", "--no-progress"])
    assert isinstance(turnpike, TurnpikeReproductionConfig)
    assert turnpike.seeds == (0, 3) and turnpike.modes == ("env",) and not turnpike.progress
    assert turnpike.out == Path("reproduction_turnpike")

    prop = parse("reproduce-turnpike-property", ["--horizons", "1", "2", "--tau", "0.5"])
    assert isinstance(prop, TurnpikePropertyConfig)
    assert prop.horizons == (1.0, 2.0) and prop.sigmas == TurnpikePropertyConfig().sigmas

    report = parse("report", ["a", "b", "--out", "r", "--seed-index", "1"])
    assert isinstance(report, ReportConfig)
    assert report.results == (Path("a"), Path("b")) and report.seed_index == 1


def test_configs_validate_as_library_objects():
    from agent_envs.training.commands.evaluate import EvaluateConfig
    from agent_envs.training.experiments.turnpike_controlled import TurnpikeReproductionConfig
    from agent_envs.training.experiments.turnpike_property import TurnpikePropertyConfig
    from agent_envs.training.experiments.uncontrolled import UncontrolledConfig
    from agent_envs.training.results.report import ReportConfig

    bad = [
        (UncontrolledConfig, {"n_agents": 0}, "--n-agents"),
        (UncontrolledConfig, {"seed": MAX_SEED + 1}, "--seed"),
        (UncontrolledConfig, {"n_agents": 10**7, "n_paths": 99}, "--n-paths"),
        (TurnpikeReproductionConfig, {"seeds": (0, 0)}, "--seeds"),
        (TurnpikeReproductionConfig, {"modes": ("bogus",)}, "--modes"),
        (TurnpikeReproductionConfig, {"n_steps": 0}, "--n-steps"),
        (TurnpikePropertyConfig, {"n_agents": 1}, "--n-agents"),
        (TurnpikePropertyConfig, {"tau": 0.3, "horizons": (1.0,)}, "--tau"),
        (TurnpikePropertyConfig, {"kernels": ("bogus",)}, "--kernels"),
        (TurnpikePropertyConfig, {"sigmas": (float("nan"),)}, "--sigmas"),
        (TurnpikePropertyConfig, {"max_iterations": 0}, "--max-iterations"),
        (EvaluateConfig, {"out": "o", "seeds": "x"}, "--seeds"),
        (EvaluateConfig, {"out": "o", "target": float("inf")}, "--target"),
        (EvaluateConfig, {"out": "o", "beta": 0}, "--beta"),
        (EvaluateConfig, {"out": "o", "policies": ("a=zero", "a=turnpike")}, "twice"),
        (EvaluateConfig, {"out": "o", "env_kwargs": "[1]"}, "--env-kwargs"),
        (ReportConfig, {"results": ("r",), "out": "o", "seed_index": -1}, "--seed-index"),
        (ReportConfig, {"results": (), "out": "o"}, "RESULTS"),
    ]
    for cls, kwargs, mention in bad:
        with pytest.raises((ValueError, TypeError), match=mention):
            cls(**kwargs)
    with pytest.raises(TypeError):
        EvaluateConfig()  # --out is required
    assert UncontrolledConfig().out == Path("out/uncontrolled")
    assert TurnpikeReproductionConfig(seeds="0-2").seeds == (0, 1, 2)


def test_defaults_are_defined_once():
    """The reproduction functions' defaults are their configs' (the CLI restated them)."""
    import inspect

    from agent_envs.training.experiments import turnpike_controlled, uncontrolled

    signature = inspect.signature(uncontrolled.reproduce).parameters
    config = uncontrolled.UncontrolledConfig()
    assert [signature[k].default for k in ("n_agents", "n_paths", "seed")] == [
        config.n_agents,
        config.n_paths,
        config.seed,
    ]
    signature = inspect.signature(turnpike_controlled.reproduce).parameters
    config = turnpike_controlled.TurnpikeReproductionConfig()
    for name in ("seeds", "n_agents", "n_steps", "n_paths"):
        assert signature[name].default == getattr(config, name), name


def test_add_dataclass_arguments_field_kinds():
    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Options:
        path: Path = dataclasses.field(metadata={"help": "a required path"})
        values: tuple[float, ...] = dataclasses.field(default=(1.0,), metadata={"help": "xs"})
        flag: bool = dataclasses.field(default=False, metadata={"help": "f"})
        quiet: bool = dataclasses.field(
            default=True,
            metadata={"help": "q", "flags": ("--loud",), "action": "store_false"},
        )
        name: str | None = dataclasses.field(
            default=None, metadata={"help": "n", "flags": ("--name", "-n")}
        )

    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, Options)
    args = parser.parse_args(["--path", "p", "--values", "2", "3", "--flag", "--loud", "-n", "x"])
    assert args.path == Path("p") and args.values == [2.0, 3.0]
    assert args.flag and not args.quiet and args.name == "x"
    assert "(default: 1.0)" in parser.format_help()
