"""Mutation testing of the core with cosmic-ray, one module at a time, on a copy of the tree.

    pip install -c constraints.txt -e ".[dev,mutation]"
    nice -n 10 python mutation/run_mutation.py                       # every module below
    nice -n 10 python mutation/run_mutation.py kernels costs --budget 600
    python mutation/run_mutation.py --report                          # scores only, no run
    python mutation/run_mutation.py --rerun-survivors                 # after adding tests
    python mutation/run_mutation.py --only-survivors swarm            # the survivors alone

Why cosmic-ray (not mutmut 3): it mutates the source file on disk and runs a plain test command
per mutant, so it works with this project's package-dir mapping (the folder baselines/ installs
as agent_envs.baselines), where mutmut 3's trampolines, which import a mutated copy by file
path, would not; its sqlite session keeps every result, so a run bounded by a time budget
resumes where it stopped and survivors can be re-run alone after new tests.

What it does, per module of `MODULES` (the file to mutate and the fast tests that guard it):
1. copies the working tree (tracked and untracked, not ignored) to `--work`/tree-NAME
   (default --work /tmp/agent-envs-mutation), with agent_envs/baselines -> ../baselines so
   that the copy is the one imported (PYTHONPATH=the copy comes before the editable
   install's finder);
2. `cosmic-ray init` (session in `--work`/sessions/NAME.sqlite, kept across runs), the
   operator filter below, `cosmic-ray baseline` (the tests must pass unmutated);
3. `cosmic-ray exec` under `timeout --budget` seconds: each mutant runs
   `python -m pytest -x -q -m "not slow" TESTS` in the copy; a failing test kills it;
4. writes mutation/reports/NAME.txt (the counts and every survivor) and prints the scores.

Operators left out (`EXCLUDED_OPERATORS`): arithmetic replaced by shifts, bitwise operators,
floor division or modulo (on float arrays they raise TypeError at once, so every test that
reaches the line kills them: they cost a test run each and say nothing), every mutation of `|`
(in these modules it is almost only the `X | None` of annotations, which `from __future__
import annotations` never evaluates: equivalent mutants by the dozen; the one runtime `|`,
`diverged_paths`' non-finite-or-too-large, is tested by test_simulator's divergence test),
comparisons replaced
by `is`/`is not`, unary minus replaced by `~`/`not`, and cosmic-ray's VariableReplacer /
VariableInserter (random variable swaps, many per line). Everything else of `core/` runs.

Not in CI (tens of minutes on 2 cores). The score and every surviving mutant, killed by a new
test or explained as equivalent, are in docs/mutation.md.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: name -> (module path, fast test files). The tests are the ones that exercise the module
#: directly; `tests/test_laws.py` checks the laws (noise variance, the centre's random walk,
#: kernel formulas, strong orders) every numerical module must obey.
MODULES: dict[str, tuple[str, list[str]]] = {
    "kernels": (
        "agent_envs/dynamics/kernels.py",
        ["tests/test_laws.py", "tests/test_dynamics.py"],
    ),
    "swarm": (
        "agent_envs/dynamics/swarm.py",
        ["tests/test_laws.py", "tests/test_dynamics.py", "tests/test_integrators.py"],
    ),
    "costs": ("agent_envs/costs.py", ["tests/test_costs.py", "tests/test_laws.py"]),
    "explicit": (
        "agent_envs/integrators/explicit.py",
        ["tests/test_laws.py", "tests/test_integrators.py"],
    ),
    "exponential": (
        "agent_envs/integrators/exponential.py",
        ["tests/test_laws.py", "tests/test_integrators.py"],
    ),
    "integrators_init": (
        "agent_envs/integrators/__init__.py",
        ["tests/test_integrators.py", "tests/test_laws.py"],
    ),
    "simulator": (
        "agent_envs/simulator.py",
        ["tests/test_laws.py", "tests/test_simulator.py", "tests/test_simulator_contract.py"],
    ),
    "episode": (
        "agent_envs/envs/episode.py",
        [
            "tests/test_env_contracts.py",
            "tests/test_envs_gym.py",
            "tests/test_envs_pettingzoo.py",
            "tests/test_env_options.py",
            "tests/test_compiled_episode.py",
            "tests/test_laws.py",
        ],
    ),
    "episode_config": (
        "agent_envs/envs/episode_config.py",
        [
            "tests/test_env_contracts.py",
            "tests/test_episode_config_contracts.py",
            "tests/test_validation.py",
            "tests/test_envs_gym.py",
        ],
    ),
    "attributes": (
        "agent_envs/envs/attributes.py",
        ["tests/test_envs_gym.py", "tests/test_step_plan.py"],
    ),
    "step_plan": (
        "agent_envs/envs/step_plan.py",
        [
            "tests/test_step_plan.py",
            "tests/test_plan_choices.py",
            "tests/test_native_switch.py",
            "tests/test_compiled_episode.py",
            "tests/test_native_cache.py",
        ],
    ),
    "swarm_env": (
        "agent_envs/envs/swarm_env.py",
        ["tests/test_env_contracts.py", "tests/test_envs_gym.py", "tests/test_compiled_episode.py"],
    ),
    "swarm_parallel": (
        "agent_envs/envs/swarm_parallel.py",
        [
            "tests/test_env_contracts.py",
            "tests/test_envs_pettingzoo.py",
            "tests/test_compiled_episode.py",
        ],
    ),
    "compiled_episode": (
        "agent_envs/envs/compiled_episode.py",
        ["tests/test_compiled_episode.py", "tests/test_step_plan.py"],
    ),
    "compiled_agents": (
        "agent_envs/envs/compiled_agents.py",
        [
            "tests/test_env_contracts.py",
            "tests/test_compiled_episode.py",
            "tests/test_envs_pettingzoo.py",
            "tests/test_native_cache.py",
        ],
    ),
    "observation": (
        "agent_envs/envs/observation.py",
        ["tests/test_envs_gym.py", "tests/test_env_options.py", "tests/test_envs_pettingzoo.py"],
    ),
    "interface": (
        "agent_envs/envs/interface.py",
        ["tests/test_env_options.py", "tests/test_envs_gym.py", "tests/test_envs_pettingzoo.py"],
    ),
    "linearization_cache": (
        "agent_envs/dynamics/linearization_cache.py",
        ["tests/test_step_plan.py", "tests/test_vector_env.py", "tests/test_compiled_lanczos.py"],
    ),
    "vector_env": (
        "agent_envs/envs/vector_env.py",
        ["tests/test_env_contracts.py", "tests/test_vector_env.py", "tests/test_native_vec_env.py"],
    ),
    "vector_blocks": (
        "agent_envs/envs/vector_blocks.py",
        ["tests/test_vector_env.py", "tests/test_step_plan.py"],
    ),
    "vector_inputs": ("agent_envs/envs/vector_inputs.py", ["tests/test_vector_env.py"]),
    "fast_step": (
        "agent_envs/envs/fast_step.py",
        [
            "tests/test_env_contracts.py",
            "tests/test_fast_step.py",
            "tests/test_step_plan.py",
            "tests/test_compiled_episode.py",
            "tests/test_native_cache.py",
        ],
    ),
    "draws": (
        "agent_envs/draws.py",
        ["tests/test_simulator.py", "tests/test_vector_env.py", "tests/test_laws.py"],
    ),
    "phi_functions": (
        "agent_envs/integrators/phi_functions.py",
        [
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
            "tests/test_integrators.py",
            "tests/test_large_swarms.py",
        ],
    ),
    "phi_dense": (
        "agent_envs/integrators/phi_dense.py",
        [
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
            "tests/test_array_backends.py",
        ],
    ),
    "phi_lanczos": (
        "agent_envs/integrators/phi_lanczos.py",
        [
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
            "tests/test_compiled_lanczos.py",
        ],
    ),
    "lanczos_stopping": (
        "agent_envs/integrators/lanczos_stopping.py",
        [
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
            "tests/test_compiled_lanczos.py",
        ],
    ),
    "lanczos_rule": (
        "agent_envs/native/lanczos_rule.py",
        ["tests/test_phi_functions.py", "tests/test_compiled_lanczos.py"],
    ),
    "phi_krylov": (
        "agent_envs/integrators/phi_krylov.py",
        [
            "tests/test_compiled_lanczos.py",
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
        ],
    ),
    "phi_arnoldi": (
        "agent_envs/integrators/phi_arnoldi.py",
        [
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
            "tests/test_array_backends.py",
        ],
    ),
    "krylov_space": (
        "agent_envs/integrators/krylov_space.py",
        [
            "tests/test_phi_functions.py",
            "tests/test_phi_contracts.py",
            "tests/test_compiled_lanczos.py",
        ],
    ),
    "phi_fused": (
        "agent_envs/integrators/phi_fused.py",
        [
            "tests/test_compiled_lanczos.py",
            "tests/test_phi_contracts.py",
            "tests/test_native_switch.py",
            "tests/test_fast_step.py",
        ],
    ),
    "phi_matrix_free": (
        "agent_envs/integrators/phi_matrix_free.py",
        ["tests/test_large_swarms.py", "tests/test_phi_contracts.py"],
    ),
    "operators": (
        "agent_envs/dynamics/operators.py",
        ["tests/test_large_swarms.py", "tests/test_dynamics.py"],
    ),
    "optimal_control": (
        "baselines/optimal_control.py",
        ["tests/test_optimal_control.py"],
    ),
}

EXCLUDED_OPERATORS = [
    r"core/ReplaceBinaryOperator_.*_(RShift|LShift|BitOr|BitAnd|BitXor|FloorDiv|Mod)$",
    r"core/ReplaceBinaryOperator_(RShift|LShift|FloorDiv|Mod)_.*",
    r"core/ReplaceBinaryOperator_(BitOr|BitAnd|BitXor)_.*",
    r"core/ReplaceComparisonOperator_(Eq|NotEq|Lt|LtE|Gt|GtE)_(Is|IsNot)$",
    r"core/ReplaceUnaryOperator_(USub|UAdd)_(Invert|Not)$",
    r"core/VariableReplacer",
    r"core/VariableInserter",
]


def copy_tree(work: Path, name: str) -> Path:
    """A fresh copy of the working tree (git's files, tracked or untracked, not ignored), one
    per module, so that two modules can run at once."""
    tree = work / f"tree-{name}"
    if tree.exists():
        shutil.rmtree(tree)
    files = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"],
        cwd=REPO,
        check=True,
        capture_output=True,
    ).stdout.split(b"\0")
    for raw in files:
        if not raw:
            continue
        rel = Path(os.fsdecode(raw))
        if not (REPO / rel).is_file():
            continue
        (tree / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, tree / rel)
    for sub in ("baselines", "training"):
        (tree / "agent_envs" / sub).symlink_to(Path("..") / sub)
    return tree


def write_config(work: Path, name: str, tree: Path, timeout: float) -> Path:
    module, tests = MODULES[name]
    tests = [t for t in tests if (tree / t).is_file()]
    python = sys.executable
    command = (
        f"env PYTHONPATH={tree} OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MPLBACKEND=Agg "
        f'{python} -m pytest -x -q -p no:cacheprovider -m "not slow" {" ".join(tests)}'
    )
    excluded = ",\n    ".join(f'"{e}"' for e in EXCLUDED_OPERATORS)
    config = work / "sessions" / f"{name}.toml"
    config.write_text(
        textwrap.dedent(
            f"""\
            [cosmic-ray]
            module-path = "{module}"
            timeout = {timeout}
            excluded-modules = []
            test-command = '''{command}'''

            [cosmic-ray.distributor]
            name = "local"

            [cosmic-ray.filters.operators-filter]
            exclude-operators = [
                {excluded}
            ]
            """
        )
    )
    return config


def counts(session: Path) -> dict[str, int]:
    """Killed / survived / incompetent / skipped / pending of a session (from its sqlite)."""
    con = sqlite3.connect(session)
    total = con.execute("select count(*) from work_items").fetchone()[0]
    rows = con.execute(
        "select worker_outcome, test_outcome, count(*) from work_results group by 1, 2"
    ).fetchall()
    con.close()
    out = {"total": total, "killed": 0, "survived": 0, "incompetent": 0, "skipped": 0}
    for worker, test, n in rows:
        worker, test = str(worker or "").upper(), str(test or "").upper()
        if worker.endswith("SKIPPED"):
            out["skipped"] += n  # operator filtered, or left out of the sample (see below)
        elif worker.endswith("ABNORMAL") or worker.endswith("EXCEPTION"):
            out["incompetent"] += n  # timeouts and crashes of the test run count as killed
        elif test.endswith("SURVIVED"):
            out["survived"] += n
        else:
            out["killed"] += n
    out["pending"] = total - sum(out[k] for k in ("killed", "survived", "incompetent", "skipped"))
    con = sqlite3.connect(session)
    out["unsampled"] = con.execute(
        "select count(*) from work_results where output = ?", (UNSAMPLED,)
    ).fetchone()[0]
    con.close()
    out["skipped"] -= out["unsampled"]
    return out


#: the output recorded for a mutant left out of a `--sample` (never run, never counted)
UNSAMPLED = "not sampled"


def sample(session: Path, size: int, seed: int) -> int:
    """Keep `size` mutants, drawn uniformly (seeded) from those not run yet, and mark the rest
    as skipped ("not sampled"); once per session, so a resumed run keeps the same sample.

    Why: a module's full run costs one test run per mutant (hundreds of runs of 10-40 s on two
    cores). The score of a uniform random sample of mutants estimates the full score without
    bias (its standard error is printed in the report); a run stopped by its time budget
    instead covers only the top of the file."""
    import random

    con = sqlite3.connect(session)
    if con.execute("select count(*) from work_results where output = ?", (UNSAMPLED,)).fetchone()[
        0
    ]:
        con.close()
        return 0
    pending = [
        row[0]
        for row in con.execute(
            "select job_id from work_items where job_id not in "
            "(select job_id from work_results) order by job_id"
        )
    ]
    left_out = sorted(
        set(pending) - set(random.Random(seed).sample(pending, min(size, len(pending))))
    )
    con.executemany(
        "insert into work_results (worker_outcome, output, test_outcome, diff, job_id) "
        "values ('SKIPPED', ?, NULL, NULL, ?)",
        [(UNSAMPLED, job) for job in left_out],
    )
    con.commit()
    con.close()
    return len(left_out)


def survivors(session: Path) -> list[tuple[int, str, str]]:
    """(line, operator, "- old || + new") of each surviving mutant, by line."""
    con = sqlite3.connect(session)
    rows = con.execute(
        "select s.start_pos_row, s.operator_name, r.diff from mutation_specs s "
        "join work_results r on r.job_id = s.job_id "
        "where upper(r.test_outcome) = 'SURVIVED' order by s.start_pos_row, s.start_pos_col"
    ).fetchall()
    con.close()
    out = []
    for row, operator, diff in rows:
        changed = [
            line.strip()
            for line in diff.splitlines()
            if line.startswith(("+", "-")) and not line.startswith(("+++", "---"))
        ]
        out.append((row, operator.removeprefix("core/"), " || ".join(changed)))
    return out


def defer_pending(session: Path) -> int:
    """Mark the mutants never run as skipped ("deferred") so that exec runs only the reset
    survivors; `undefer` makes them pending again."""
    con = sqlite3.connect(session)
    cur = con.execute(
        "insert into work_results (worker_outcome, output, test_outcome, diff, job_id) "
        "select 'SKIPPED', 'deferred', NULL, NULL, job_id from work_items "
        "where job_id not in (select job_id from work_results)"
    )
    con.commit()
    con.close()
    return cur.rowcount


def undefer(session: Path) -> None:
    con = sqlite3.connect(session)
    con.execute("delete from work_results where output = 'deferred'")
    con.commit()
    con.close()


def reset_survivors(session: Path) -> int:
    """Forget the survivors' results so that `cosmic-ray exec` runs them again."""
    con = sqlite3.connect(session)
    cur = con.execute("delete from work_results where test_outcome like '%SURVIVED'")
    con.commit()
    con.close()
    return cur.rowcount


def run(cmd: list[str], cwd: Path, timeout: float | None = None) -> int:
    print("$", " ".join(cmd), flush=True)
    try:
        return subprocess.run(cmd, cwd=cwd, timeout=timeout).returncode
    except subprocess.TimeoutExpired:
        print(f"  stopped after the budget of {timeout:.0f} s (resume by running again)")
        return -1


def mutate(
    name: str,
    work: Path,
    budget: float,
    timeout: float,
    rerun: bool,
    init_only: bool = False,
    only_survivors: bool = False,
    sample_size: int | None = None,
    sample_seed: int = 0,
) -> None:
    tree = copy_tree(work, name)  # fresh sources: a run stopped mid-mutant leaves a mutant
    config = write_config(work, name, tree, timeout)
    session = work / "sessions" / f"{name}.sqlite"
    bindir = Path(sys.executable).parent
    if not session.exists():
        run([str(bindir / "cosmic-ray"), "init", str(config), str(session)], tree)
    if session.exists():
        undefer(session)  # left by an interrupted --only-survivors run
    if only_survivors and session.exists():
        print(f"{name}: {defer_pending(session)} mutants not run yet are deferred")
    if rerun or only_survivors:
        print(f"{name}: {reset_survivors(session)} survivors to run again")
    run([str(bindir / "cr-filter-operators"), str(session), str(config)], tree)
    if sample_size is not None:
        print(f"{name}: {sample(session, sample_size, sample_seed)} mutants left out of the sample")
    if init_only:
        return
    if run([str(bindir / "cosmic-ray"), "baseline", str(config)], tree) != 0:
        raise SystemExit(f"{name}: the tests fail on the unmutated tree")
    try:
        run([str(bindir / "cosmic-ray"), "exec", str(config), str(session)], tree, budget)
    finally:
        if only_survivors:
            undefer(session)
    write_report(name, work)


def score(c: dict[str, int]) -> str:
    """killed (crashes and timeouts included) / run, before equivalent mutants are set aside
    (docs/mutation.md does that by hand), with the binomial standard error of a sample."""
    killed = c["killed"] + c["incompetent"]
    run_ = killed + c["survived"]
    if not run_:
        return "-"
    p = killed / run_
    return f"{100 * p:.1f}%" + (
        f"+-{100 * (p * (1 - p) / run_) ** 0.5:.1f}" if c["unsampled"] else ""
    )


def write_report(name: str, work: Path) -> None:
    """mutation/reports/NAME.txt: the counts and every surviving mutant (line, operator,
    change); `cr-report SESSION` prints cosmic-ray's full report from the kept session."""
    session = work / "sessions" / f"{name}.sqlite"
    if not session.exists():
        return
    c = counts(session)
    module, tests = MODULES[name]
    lines = [
        f"module: {module}",
        f"tests: {' '.join(tests)}",
        "mutants: {total}, killed: {killed}, survived: {survived}, test run crashed or timed "
        "out (counted killed): {incompetent}, operator filtered: {skipped}, not run: "
        "{pending}, left out of the sample: {unsampled}".format(**c),
        f"score (killed / run, equivalent mutants not set aside): {score(c)}",
        "",
        "survivors (line, operator, change):",
    ]
    lines += [f"{row} {operator}: {change}" for row, operator, change in survivors(session)]
    reports = REPO / "mutation" / "reports"
    reports.mkdir(parents=True, exist_ok=True)
    (reports / f"{name}.txt").write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("modules", nargs="*", choices=[[], *MODULES], default=[])
    parser.add_argument("--work", type=Path, default=Path("/tmp/agent-envs-mutation"))
    parser.add_argument("--budget", type=float, default=600.0, help="seconds per module")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds per mutant")
    parser.add_argument("--rerun-survivors", action="store_true")
    parser.add_argument(
        "--only-survivors", action="store_true", help="re-run the survivors and nothing else"
    )
    parser.add_argument(
        "--sample",
        type=int,
        default=None,
        help="run a seeded uniform sample of this many mutants (fixed at a session's first run)",
    )
    parser.add_argument("--sample-seed", type=int, default=0)
    parser.add_argument("--report", action="store_true", help="print the scores, run nothing")
    parser.add_argument("--init-only", action="store_true", help="create the sessions, run none")
    parser.add_argument("--survivors", action="store_true", help="list the surviving mutants")
    parser.add_argument("--write-reports", action="store_true", help="rewrite the reports only")
    args = parser.parse_args()
    names = args.modules or list(MODULES)
    (args.work / "sessions").mkdir(parents=True, exist_ok=True)
    if args.write_reports:
        for name in names:
            write_report(name, args.work)
    if args.survivors:
        for name in names:
            session = args.work / "sessions" / f"{name}.sqlite"
            if session.exists():
                for row, operator, change in survivors(session):
                    print(f"{MODULES[name][0]}:{row} {operator}: {change}")
        return
    if not args.report:
        for name in names:
            mutate(
                name,
                args.work,
                args.budget,
                args.timeout,
                args.rerun_survivors,
                args.init_only,
                args.only_survivors,
                args.sample,
                args.sample_seed,
            )
    print(
        f"{'module':<18} {'mutants':>7} {'killed':>6} {'survived':>8} {'crash':>5} "
        f"{'skipped':>7} {'pending':>7} {'unsampled':>9} {'score':>6}"
    )
    for name in names:
        session = args.work / "sessions" / f"{name}.sqlite"
        if session.exists():
            c = counts(session)
            print(
                f"{name:<18} {c['total']:>7} {c['killed']:>6} {c['survived']:>8} "
                f"{c['incompetent']:>5} {c['skipped']:>7} {c['pending']:>7} "
                f"{c['unsampled']:>9} {score(c):>6}"
            )


if __name__ == "__main__":
    main()
