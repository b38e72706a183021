"""Runs are never lost or mixed, tried with real ``python train.py`` processes: SIGINT / SIGTERM stop at
a checkpoint and resume exactly, two runs never share a directory, bad input leaves nothing behind,
unknown keys are refused with the nearest valid one, log lines never glue onto the progress bar."""

from __future__ import annotations

import io
import logging
import os
import re
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from conftest import (
    TRAIN_PY,
    TRAIN_TIMEOUT,
    agent_meta,
    read_metrics,
    run_train,
    start_train,
    train_env,
    without_timing,
)

from dqn_transfer.experiments import sweeps
from dqn_transfer.storage.checkpoint import load_training_state
from dqn_transfer.training.trainer import log_above_bars

pytestmark = pytest.mark.slow

MAP = "0...T\n.#...\n...#.\nX....\n1..T.\n"  # 5 x 5, two chests, one trap, two agents
BASE = (
    "env.layout_file=map.txt",
    "env.size=5",
    "env.num_treasures=2",
    "env.num_traps=1",
    "env.num_agents=2",
    "env.complexity=0.08",
    "env.map_seed=0",
    "eval_episodes=2",
)
LONG_RUN = (
    *BASE,
    "agent=dqn",
    "mode=cooperative",
    "agent.learning_starts=100",
    "agent.hidden=[32]",
    "agent.batch_size=32",
    "total_steps=1500",
    "checkpoint_every=100000",
    "eval_every=100",
    "seed=5",
)


@pytest.fixture(scope="module")
def launch(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("safety")
    (path / "map.txt").write_text(MAP)
    return path


def metrics(run_dir: Path) -> list[dict]:
    return without_timing(read_metrics(run_dir))


def agent_digests(run_dir: Path) -> list[str]:
    return [agent_meta(run_dir / "checkpoints" / f"agent_{i}.safetensors")["digest"] for i in (0, 1)]


def wait_for_evaluations(run_dir: Path, count: int, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while len(metrics(run_dir)) < count:
        assert proc.poll() is None, f"the run ended before {count} evaluations"
        assert time.monotonic() < deadline, "the run is too slow to reach its evaluations"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def signalled(launch):
    """The same run uninterrupted, stopped by SIGINT and by SIGTERM, each resumed to the end."""
    reference = start_train(launch, *LONG_RUN, run_dir=launch / "reference")
    outcomes = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        # One at a time: a run started beside the first one could finish its loop while the first is
        # being stopped, and a signal sent after the loop meets the default handler.
        run_dir = launch / signal.Signals(signum).name
        proc = start_train(launch, *LONG_RUN, run_dir=run_dir)
        wait_for_evaluations(run_dir, 4, proc)
        sent = time.monotonic()
        proc.send_signal(signum)
        code = proc.wait(timeout=60)
        outcomes[signum] = dict(
            code=code,
            within=time.monotonic() - sent,
            run_dir=run_dir,
            output=run_dir.with_suffix(".out").read_text(),
            step=load_training_state(run_dir / "checkpoints" / "training_state.safetensors")[1]["counters"]["step"],
        )
    for outcome in outcomes.values():
        outcome["resumed"] = run_train(launch, "resume=true", run_dir=outcome["run_dir"])
    assert reference.wait(timeout=TRAIN_TIMEOUT) == 0
    return launch / "reference", outcomes


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_checkpoints_says_how_to_resume_and_exits_with_its_code(signalled, signum, code):
    _, outcomes = signalled
    out = outcomes[signum]
    assert out["code"] == code
    assert out["within"] < 10  # it stops after the step in progress, with a checkpoint
    assert "Traceback" not in out["output"]
    line = f"interrupted at step {out['step']}; resume with: python train.py resume=true hydra.run.dir={out['run_dir']}"
    assert line in out["output"]
    assert f"run directory: {out['run_dir']}" in out["output"].splitlines()[0]  # said first, not only at the end
    assert 0 < out["step"] < 1500


def test_a_resumed_run_names_its_directory_first(signalled):
    """Its first line is ``run directory: ...``, then ``resumed ... at step N`` (issue #31: the resume's line came
    first)."""
    _, outcomes = signalled
    for out in outcomes.values():
        first, second = out["resumed"].output.splitlines()[:2]
        assert first.endswith(f"run directory: {out['run_dir']}"), first
        assert f"resumed {out['run_dir']} at step {out['step']}" in second, second


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_resuming_after_a_signal_gives_the_uninterrupted_run(signalled, signum):
    reference, outcomes = signalled
    run_dir = outcomes[signum]["run_dir"]
    assert metrics(run_dir) == metrics(reference)
    assert agent_digests(run_dir) == agent_digests(reference)


def test_a_signal_stops_a_long_evaluation_within_seconds_and_records_none_of_it(launch):
    """SIGTERM in the step-0 evaluation of a million episodes (SLURM's grace period is seconds): the run stops
    at once with its checkpoint, and the unfinished evaluation is not written as if complete."""
    run_dir = launch / "long_evaluation"
    proc = start_train(launch, *BASE, "agent=sarsa", "eval_episodes=1000000", run_dir=run_dir)
    deadline = time.monotonic() + 60
    while "run directory:" not in run_dir.with_suffix(".out").read_text():  # the evaluation starts right after
        assert proc.poll() is None and time.monotonic() < deadline, run_dir.with_suffix(".out").read_text()
        time.sleep(0.05)
    time.sleep(1)
    sent = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 143
    assert time.monotonic() - sent < 10
    output = run_dir.with_suffix(".out").read_text()
    assert "Traceback" not in output and "the evaluation at step 0 was stopped unfinished" in output, output
    assert metrics(run_dir) == []
    assert load_training_state(run_dir / "checkpoints" / "training_state.safetensors")[1]["counters"]["step"] == 0


def test_two_runs_started_in_the_same_second_get_their_own_directories(tmp_path):
    (tmp_path / "map.txt").write_text(MAP)
    command = [sys.executable, str(TRAIN_PY), *BASE, "agent=sarsa", "total_steps=50", "eval_every=25", "progress=false"]
    procs = [
        subprocess.Popen(
            command, cwd=tmp_path, env=train_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for _ in range(2)
    ]
    outputs = [p.communicate(timeout=TRAIN_TIMEOUT)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    runs = sorted((tmp_path / "outputs" / "runs").glob("*/*"))
    assert len(runs) == 2
    for run in runs:  # each run's files are its own: one event file, evaluations at 0, 25, 50 once
        assert [m["step"] for m in metrics(run)] == [0, 25, 50]
        assert len(list((run / "tb").glob("events.*"))) == 1


def test_a_second_process_on_a_directory_in_use_is_refused_and_changes_nothing(launch):
    run_dir = launch / "busy"
    first = start_train(launch, *LONG_RUN, "total_steps=1000000", run_dir=run_dir)  # busy until stopped
    wait_for_evaluations(run_dir, 1, first)
    config_before = (run_dir / ".hydra" / "config.yaml").read_bytes()
    for extra in ((), ("resume=true",)):
        second = run_train(launch, *LONG_RUN, *extra, run_dir=run_dir, check=False)
        assert second.returncode == 1
        assert f"error: {run_dir} is in use by another running process" in second.stderr
        assert "Traceback" not in second.output
    assert (run_dir / ".hydra" / "config.yaml").read_bytes() == config_before
    first.send_signal(signal.SIGTERM)
    assert first.wait(timeout=60) == 143


def _tree(path: Path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*"))


BAD = {
    "out_of_range": ("agent.gamma=1.5",),
    "typo": ("agent.learning_rate=0.5",),
    "appended_typo": ("+agent.learning_rate=0.5",),
    "no_such_option": ("agent=ppo",),
    "missing_source": ("transfer=on", "transfer.source=nowhere.safetensors"),
    "resume_nothing": ("resume=true",),
}


# Refused before Hydra runs (a typo) and after it made the run directory (a bad value): also tried in an
# existing, empty directory, which must stay as it was.
EXISTING_TOO = ("typo", "out_of_range")


@pytest.fixture(scope="module")
def refusals(tmp_path_factory):
    """Each bad command into a fresh default directory (some also into an empty existing one)."""
    root = tmp_path_factory.mktemp("refusals")
    jobs = []
    for name, overrides in BAD.items():
        for where in ("default", "existing") if name in EXISTING_TOO else ("default",):
            cwd = root / f"{name}_{where}"
            cwd.mkdir()
            (cwd / "map.txt").write_text(MAP)
            if where == "existing":
                (cwd / "empty_run").mkdir()
            jobs.append(
                (cwd, (*BASE, "total_steps=10", *overrides), cwd / "empty_run" if where == "existing" else None)
            )
    with ThreadPoolExecutor(max_workers=2) as pool:
        outputs = list(pool.map(lambda job: run_in(*job), jobs))
    return {cwd.name: (result, _tree(cwd)) for (cwd, _, _), result in zip(jobs, outputs)}


def run_in(cwd: Path, overrides: tuple[str, ...], run_dir: Path | None) -> subprocess.CompletedProcess:
    """``python train.py OVERRIDES`` in ``cwd``; no ``run_dir`` means Hydra's default directory."""
    command = [sys.executable, str(TRAIN_PY), *overrides, "progress=false"]
    if run_dir is not None:
        command.append(f"hydra.run.dir={run_dir}")
    return subprocess.run(command, cwd=cwd, env=train_env(), capture_output=True, text=True, timeout=TRAIN_TIMEOUT)


@pytest.mark.parametrize("name", list(BAD))
def test_a_refused_run_leaves_nothing_behind(refusals, name):
    for where, expected in (("default", ["map.txt"]), ("existing", ["empty_run", "map.txt"])):
        if f"{name}_{where}" not in refusals:
            continue
        result, tree = refusals[f"{name}_{where}"]
        assert result.returncode == 1, result.stderr
        errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
        assert tree == expected, (where, tree)


def test_unknown_keys_name_the_nearest_valid_one(refusals):
    assert (
        "error: unknown config key 'agent.learning_rate' in 'agent.learning_rate=0.5' (did you mean agent.lr?)"
        in refusals["typo_default"][0].stderr
    )
    assert "in '+agent.learning_rate=0.5' (did you mean agent.lr?)" in refusals["appended_typo_default"][0].stderr
    assert (
        "error: agent=ppo: no such option (choose from double_dqn, dqn, qlearning, sarsa)"
        in refusals["no_such_option_default"][0].stderr
    )


def test_a_run_directory_beneath_a_file_is_one_line(tmp_path):
    (tmp_path / "map.txt").write_text(MAP)
    (tmp_path / "a_file").write_text("x")
    result = run_train(tmp_path, *BASE, "total_steps=10", run_dir=tmp_path / "a_file" / "run", check=False)
    assert result.returncode == 1 and "Traceback" not in result.output
    assert (
        f"error: cannot use {tmp_path / 'a_file' / 'run'} as a run directory: {tmp_path / 'a_file'} is a file"
        in result.stderr
    )


def run_interleaved(command: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """Run ``command`` to a successful end with one output stream, as on a terminal: the bar (stderr)
    and the log lines (stdout) interleave in ``stdout``."""
    result = subprocess.run(
        command,
        cwd=cwd,
        env=train_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=TRAIN_TIMEOUT,
    )
    assert result.returncode == 0, result.stdout
    return result


def test_log_lines_never_glue_onto_the_progress_bar(tmp_path):
    (tmp_path / "map.txt").write_text(MAP)
    command = [
        sys.executable,
        str(TRAIN_PY),
        *BASE,
        "agent=sarsa",
        "total_steps=3000",
        "eval_every=500",
        "progress=true",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    result = run_interleaved(command, tmp_path)
    # The bar redraws with carriage returns; every log line must start a line of its own.
    pieces = result.stdout.replace("\r", "\n").splitlines()
    evals = [p for p in pieces if "eval step" in p]
    assert len(evals) == 7 and all(p.startswith("[") for p in evals), evals


def test_parallel_jobs_tag_their_lines(tmp_path):
    (tmp_path / "map.txt").write_text(MAP)
    command = [
        sys.executable,
        str(TRAIN_PY),
        "-m",
        *BASE,
        "agent=sarsa",
        "total_steps=20",
        "eval_every=10",
        "progress=false",
        "seed=0,1",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    ]
    result = subprocess.run(
        command, cwd=tmp_path, env=train_env(), capture_output=True, text=True, timeout=TRAIN_TIMEOUT
    )
    assert result.returncode == 0, result.stderr
    for job in (0, 1):
        log = (tmp_path / "sweep" / str(job) / "train.log").read_text()
        evals = [line for line in log.splitlines() if "eval step" in line]
        assert len(evals) == 3 and all(f"- [job {job}] eval step" in line for line in evals), evals
    # The same sweep again into the same folder: refused before any job's record is rewritten.
    record = (tmp_path / "sweep" / "0" / ".hydra" / "config.yaml").read_bytes()
    again = subprocess.run(
        command, cwd=tmp_path, env=train_env(), capture_output=True, text=True, timeout=TRAIN_TIMEOUT
    )
    assert again.returncode == 1 and "Traceback" not in again.stderr + again.stdout
    assert f"error: {tmp_path / 'sweep'} already holds the runs of a sweep (0, 1)" in again.stderr
    assert (tmp_path / "sweep" / "0" / ".hydra" / "config.yaml").read_bytes() == record


LOG_STAMP = re.compile(r"\[\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}\]")


def assert_log_lines_start_lines(output: str) -> None:
    """Every log line starts a line of its own in ``output`` (a captured stdout + stderr): no carriage
    return before it (a bar redrawn and overwritten), nothing glued before its time stamp."""
    for line in output.split("\n"):
        stamps = [match.start() for match in LOG_STAMP.finditer(line)]
        assert stamps in ([], [0]) and (not stamps or "\r" not in line), repr(line)


def test_a_log_line_reaches_the_stream_in_one_write(monkeypatch):
    """Two jobs of a sweep share one pipe: a line written as message, then newline, lets the other job's
    line in between (a joblib sweep printed ``...eval step 1500: ...[2026-12-06 22:49:09,901]...[job 1]``)."""
    writes: list[str] = []

    class Recording(io.StringIO):
        def write(self, s: str) -> int:
            writes.append(s)
            return super().write(s)

    monkeypatch.setattr(sys, "stderr", Recording())  # a console stream: the one the bars' redirect takes over
    logger = logging.getLogger("test_a_log_line_reaches_the_stream_in_one_write")
    logger.propagate = False
    logger.addHandler(logging.StreamHandler(sys.stderr))
    with log_above_bars([logger]):
        logger.warning("[job 0] eval step 1500: team_return 195.0")
    assert [w for w in writes if w] == ["[job 0] eval step 1500: team_return 195.0\n"]


@pytest.mark.parametrize("launcher", ["basic", "joblib"])
def test_a_sweeps_captured_output_glues_no_line_onto_a_progress_bar(tmp_path, launcher):
    """Two jobs of a multirun, progress on (the default), stdout and stderr captured in one stream: a
    joblib sweep once printed ``93%|█████████▎| 2800/3000 [...][2026-12-02 10:52:30,783]...[job 0] done:``.
    The basic launcher's is checked too: CI does not install the joblib plugin."""
    if launcher == "joblib":
        pytest.importorskip("hydra_plugins.hydra_joblib_launcher", reason="the sweep extra is not installed")
    (tmp_path / "map.txt").write_text(MAP)
    command = [
        sys.executable,
        str(TRAIN_PY),
        "-m",
        *BASE,
        "agent=sarsa",
        "total_steps=3000",
        "eval_every=500",
        "progress=true",
        "seed=0,1",
        f"hydra/launcher={launcher}",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    ]
    if launcher == "joblib":
        command.append("hydra.launcher.n_jobs=2")
    result = run_interleaved(command, tmp_path)
    assert_log_lines_start_lines(result.stdout)
    for job in (0, 1):
        assert sum(f"[job {job}] eval step" in line for line in result.stdout.splitlines()) == 7, result.stdout


def test_an_interrupted_study_stage_continues_where_it_stopped(tmp_path, monkeypatch, capsys):
    """A stage of the study (a multirun) stopped by Ctrl-C part-way is run again with the same settings:
    it continues, each job from its checkpoint, and ends as the stage run in one go; its wall time is
    both attempts'."""
    (tmp_path / "map.txt").write_text(MAP)
    overrides = (
        *LONG_RUN,
        *("total_steps=12000", "checkpoint_every=500", "eval_every=500", "replicas.seeds=1", "replicas.maps=1"),
        *("mode=cooperative", "seed=0,1"),  # 2 jobs, one after the other
    )

    def stage(name: str) -> sweeps.Multirun:  # claim 1's experiment on LONG_RUN's map and learner
        return sweeps.Multirun(name, "claim1", overrides, tmp_path / name, 2, {"settings": "same"})

    sweeps.run_multirun(stage("reference"), tmp_path, "basic", 1, poll_seconds=0.2)
    started: list[subprocess.Popen] = []
    popen = subprocess.Popen

    def own_group(*args, **kwargs):  # the stage's process in a group of its own, for the Ctrl-C below
        started.append(popen(*args, start_new_session=True, **kwargs))
        return started[-1]

    monkeypatch.setattr(sweeps.subprocess, "Popen", own_group)
    with ThreadPoolExecutor(1) as pool:
        first = pool.submit(sweeps.run_multirun, stage("stopped"), tmp_path, "basic", 1, poll_seconds=0.2)
        deadline = time.monotonic() + TRAIN_TIMEOUT
        while len(metrics(tmp_path / "stopped" / "0")) < 4:  # job 0 in its loop, job 1 not started
            assert time.monotonic() < deadline and not first.done()
            time.sleep(0.05)
        os.killpg(started[0].pid, signal.SIGINT)
        with pytest.raises(sweeps.ReproduceError):
            first.result(timeout=120)
    monkeypatch.undo()
    assert not sweeps.run_is_complete(tmp_path / "stopped" / "0")
    capsys.readouterr()
    sweeps.run_multirun(stage("stopped"), tmp_path, "basic", 1, poll_seconds=0.2)
    assert "[stopped] continuing where it stopped: 0/2 runs complete" in capsys.readouterr().out
    for job in ("0", "1"):
        assert metrics(tmp_path / "stopped" / job) == metrics(tmp_path / "reference" / job)
        assert agent_digests(tmp_path / "stopped" / job) == agent_digests(tmp_path / "reference" / job)
    stamp = sweeps.read_stamp(tmp_path / "stopped")
    assert len(stamp["attempt_seconds"]) == 2 and stamp["wall_seconds"] == sum(stamp["attempt_seconds"])


def test_a_multiruns_finished_job_is_read_once_while_the_others_run(tmp_path, monkeypatch, capsys):
    # The study's progress lines poll every job: a finished one (its configs and metrics parsed) is not read
    # again at every poll, which for a tuning search's 24 jobs of 5 replicas kept the study's process at an
    # eighth of a core.
    sweep = tmp_path / "sweep"
    reads: dict[str, int] = {"0": 0, "1": 0}
    polls = iter([None] * 6)

    class Process:  # the multirun: job 0 is finished from the start, job 1 when the process ends
        returncode: int | None = None

        def __init__(self, *args, **kwargs):
            for job in reads:
                (sweep / job).mkdir()

        def poll(self):
            self.returncode = next(polls, 0)
            return self.returncode

    started: list[Process] = []

    def complete(run_dir: Path) -> bool:
        reads[run_dir.name] += 1
        return run_dir.name == "0" or started[-1].returncode == 0

    monkeypatch.setattr(sweeps.subprocess, "Popen", lambda *a, **k: started.append(Process()) or started[-1])
    monkeypatch.setattr(sweeps, "run_is_complete", complete)

    multirun = sweeps.Multirun("search", "claim1", (), sweep, 2, {"settings": "same"})
    sweeps.run_multirun(multirun, tmp_path, "basic", 1, poll_seconds=0.001)
    assert "[search] 1/2 runs done" in capsys.readouterr().out
    assert reads["0"] == 1 + 1  # once while polling, once in the end's check of every job
    assert reads["1"] == 6 + 1  # at each of the 6 polls while it ran
