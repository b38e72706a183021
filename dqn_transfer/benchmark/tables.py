"""The benchmark's Markdown table, from its JSON document (:func:`~dqn_transfer.benchmark.suite.run_benchmark`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

Doc = dict[str, Any]
Column = tuple[str, Callable[[Any], str]]  # a heading, and the cell of a row under it


def _fmt(x: float, digits: int = 0) -> str:
    return f"{x:,.{digits}f}"


def _x(ratio: float) -> str:
    return f"{ratio:.2f}x"


def _part(
    heading: str, text: str, columns: Sequence[Column], rows: Iterable[Any], label_column: bool = False
) -> list[str]:
    """One section of the table: heading, explanation, and a Markdown table whose columns are right-aligned
    numbers (the first one left-aligned when it holds labels)."""
    align = ["---" if label_column else "---:"] + ["---:"] * (len(columns) - 1)
    return [
        heading,
        "",
        text,
        "",
        f"| {' | '.join(name for name, _ in columns)} |",
        f"|{'|'.join(align)}|",
        *(f"| {' | '.join(cell(row) for _, cell in columns)} |" for row in rows),
    ]


def _env_table(res: Doc) -> list[str]:
    s = res["settings"]
    return _part(
        f"## 1. Environment throughput (random actions, {s['sizes']['env_steps']:,} joint steps, resets included)",
        f"Map: {s['env_map']} generated for K starts. Wall clock.",
        [
            ("agents", lambda row: str(row["num_agents"])),
            ("PettingZoo ParallelEnv steps/s", lambda row: _fmt(row["pettingzoo_steps_per_s"])),
            ("numpy core steps/s", lambda row: _fmt(row["core_steps_per_s"])),
            ("core / PettingZoo", lambda row: _x(row["core_over_pettingzoo"])),
        ],
        res["env"],
    )


def _training_table(res: Doc) -> list[str]:
    s = res["settings"]
    hp, steps = s["hyperparameters"], s["sizes"]["train_steps"]
    return _part(
        f"## 2. DQN training on TreasureHunt-v0 ({steps:,} env steps, "
        f"{max(0, steps - hp['learning_starts']):,} gradient steps)",
        f"Map: {s['source_map']} (one chest, 6 moves from the start). Ours: `Trainer(source_task=True).run()` "
        "(the training loop with its TensorBoard logging; progress bar off; its greedy evaluations and "
        'checkpoint writes timed and subtracted). SB3: `DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0"), '
        f"...).learn()`. Matched: {_hyperparameters(hp)}. Greedy success: fraction of greedy episodes "
        "reaching the chest after training (same episode loop for both), mean over repeats.",
        [
            ("torch threads", lambda row: str(row["torch_threads"])),
            ("ours steps/s", lambda row: _fmt(row["ours"]["steps_per_s"])),
            ("SB3 steps/s", lambda row: _fmt(row["sb3"]["steps_per_s"])),
            ("ours / SB3 (wall)", lambda row: _x(row["ours_over_sb3"])),
            ("ours / SB3 (CPU)", lambda row: _x(row["ours_over_sb3_cpu"])),
            ("ours greedy success", lambda row: _fmt(row["ours"]["greedy_success"], 2)),
            ("SB3 greedy success", lambda row: _fmt(row["sb3"]["greedy_success"], 2)),
        ],
        res["training"],
    )


def _team_table(res: Doc) -> list[str]:
    s = res["settings"]
    return _part(
        f"## 3. Per-step cost as the team grows ({s['sizes']['team_steps']} timed joint steps, "
        "every one with a gradient update)",
        f"ms per joint env step = act + env step + replay store + gradient update (batch "
        f"{s['hyperparameters']['batch_size']} per agent), wall clock, after {s['team_learning_starts']} untimed "
        f"replay-filling steps; map {s['env_map']} generated for K starts, same hyperparameters. Batched: one "
        "DQNLearner for the K agents (stacked weights, one Adam step). Separate: K single-agent DQNLearners "
        "stepped in a Python loop.",
        [
            ("K", lambda row: str(row["num_agents"])),
            ("batched ms/step", lambda row: _fmt(row["batched"]["ms_per_step"], 2)),
            ("batched ms/agent-step", lambda row: _fmt(row["batched"]["ms_per_agent_step"], 2)),
            ("batched vs K=1", lambda row: _x(row["batched_over_k1"])),
            ("separate ms/step", lambda row: _fmt(row["separate"]["ms_per_step"], 2)),
            ("separate ms/agent-step", lambda row: _fmt(row["separate"]["ms_per_agent_step"], 2)),
            ("separate / batched (wall)", lambda row: _x(row["separate_over_batched"])),
            ("separate / batched (CPU)", lambda row: _x(row["separate_over_batched_cpu"])),
        ],
        res["team"],
    )


UPDATE_LABELS = {
    "bare": "bare PyTorch, nn.Sequential, pre-sampled batch",
    "in_memory": "ours without the replay sample: DQNLearner.train_on(pre-sampled batch)",
    "ours": "DQNLearner.gradient_step (replay sample + update + per-agent loss/Q stats)",
    "sample": "of which ReplayBuffer.sample",
    "sb3": "SB3 DQN.train, per gradient step (replay sample included)",
    "bare_default_threads": "bare PyTorch, nn.Sequential, {threads} threads (torch default)",
    "ours_default_threads": "DQNLearner.gradient_step, {threads} threads (torch default)",
}


def _update_table(res: Doc) -> list[str]:
    u = res["update"]
    return _part(
        f"## 4. Time per gradient update (K = 1, obs 100, batch {res['settings']['hyperparameters']['batch_size']}, "
        f"{u['updates']:,} updates per timing)",
        "Bare = CleanRL-style update of an nn.Sequential on a batch already in memory as tensors (target "
        "max under no_grad, gather, Huber loss, backward, clip_grad_norm_, Adam step).",
        [
            ("update", lambda key: UPDATE_LABELS[key].format(threads=u["default_threads"])),
            ("wall us/update", lambda key: _fmt(u["timings"][key]["wall_us"])),
            ("CPU us/update", lambda key: _fmt(u["timings"][key]["cpu_us"])),
            ("vs bare (wall)", lambda key: _x(u["timings"][key]["over_bare"])),
            ("vs bare (CPU)", lambda key: _x(u["timings"][key]["over_bare_cpu"])),
        ],
        (key for key in UPDATE_LABELS if key in u["timings"]),
        label_column=True,
    )


def _machine_line(res: Doc, load: Doc) -> str:
    """The machine, and the load average (1 min) when the section started and ended."""
    m = res["machine"]
    during = (
        f"; load average (1 min) {load['start'][0]:.2f} at the start of this section, {load['end'][0]:.2f} at its end"
        if load["start"] and load["end"]
        else ""
    )
    return f"Machine: {m['cpu_model']}, {m['cpus_available']} cores{during}."


def _hyperparameters(hp: Doc) -> str:
    return (
        f"MLP {hp['hidden']}, Adam lr {hp['lr']:g}, batch {hp['batch_size']}, replay {hp['buffer_size']:,}, "
        f"learning_starts {hp['learning_starts']:,}, train_freq {hp['train_freq']}, gradient_steps "
        f"{hp['gradient_steps']}, target copy every {hp['target_update']:,} steps (tau {hp['tau']}), gamma "
        f"{hp['gamma']}, epsilon {hp['eps_start']} -> {hp['eps_end']} over {hp['exploration_fraction']} of the "
        f"run, Huber loss, max_grad_norm {hp['max_grad_norm']}, CPU"
    )


def _map(kwargs: Doc) -> str:
    return (
        f"{kwargs['size']}x{kwargs['size']} map ({kwargs['num_treasures']} chest(s), {kwargs['num_traps']} "
        f"trap(s), complexity {kwargs['complexity']}, map seed {kwargs['map_seed']})"
    )


LONE_LABELS = {
    "ours": "ours: `python -m dqn_transfer.cli.train agent.engine=numpy` (`train.py`)",
    "ours_torch": "ours, torch engine: `python -m dqn_transfer.cli.train agent.engine=torch`",
    "sb3": 'SB3: `DQN("MlpPolicy", gymnasium.make("TreasureHunt-v0")).learn()`',
    "bare": "bare PyTorch: a CleanRL-style dqn.py loop",
}


def _lone_table(res: Doc) -> list[str]:
    lone = res["lone"]
    c = lone["contenders"]
    return _part(
        f"## 5. Whole process, one DQN learner ({lone['steps']:,} env steps, "
        f"{c['ours']['figures']['gradient_steps']:,} gradient steps)",
        f"{_machine_line(res, lone['load'])} Settings: one agent on a {_map(lone['map'])}, each program trains "
        f"{lone['steps']:,} env steps with {_hyperparameters(lone['hyperparameters'])}, one torch thread. Wall: "
        "from spawn to exit (imports, setup, and ours' two one-episode evaluations, TensorBoard logging and "
        "final checkpoint included); CPU: user + system of the process (os.wait4). Ours observes the "
        "team game's position + chest-state inputs, SB3 and bare the position inputs of TreasureHunt-v0. "
        "ours / this: ours' steps/s over this program's, paired by repeat (> 1: ours is faster).",
        [
            ("program", lambda who: LONE_LABELS[who]),
            ("wall s", lambda who: _fmt(c[who]["figures"]["seconds"], 1)),
            ("steps/s", lambda who: _fmt(c[who]["figures"]["steps_per_s"])),
            ("CPU s", lambda who: _fmt(c[who]["figures"]["cpu_seconds"], 1)),
            ("steps/CPU-s", lambda who: _fmt(c[who]["figures"]["steps_per_cpu_s"])),
            ("peak RSS MB", lambda who: _fmt(c[who]["figures"]["max_rss_mb"])),
            ("gradient steps", lambda who: _fmt(c[who]["figures"]["gradient_steps"])),
            ("ours / this (wall)", lambda who: _x(c[who]["ours_over_this"])),
            ("ours / this (CPU)", lambda who: _x(c[who]["ours_over_this_cpu"])),
        ],
        (who for who in LONE_LABELS if who in c),
        label_column=True,
    )


def _replicas_table(res: Doc) -> list[str]:
    rep = res["replicas"]
    sb3, k = rep["sb3"], rep["team_agents"]
    return _part(
        f"## 6. Sweep throughput: R replicas of a {k}-agent team in one command, against SB3 one learner "
        f"per process ({rep['steps']:,} env steps per process)",
        f"{_machine_line(res, rep['load'])} Settings: a cooperative team of {k} DQN agents on a "
        f"{_map(rep['map'])}, {rep['steps']:,} joint env steps, {_hyperparameters(rep['hyperparameters'])}. "
        "Ours: ONE `python -m dqn_transfer.cli.train replicas.seeds=R agent.engine=E "
        f"threads={rep['ours_threads']}` command (R x {k} learners, batched; `replicas.workers=auto` splits the "
        "replicas across worker processes, one per core); learner-steps/s = steps x R x "
        f"{k} / whole-command wall, CPU of every process it waited for. SB3: "
        f"{rep['sb3_processes']} `DQN.learn` processes (TreasureHunt-v0 of the map, one learner each, one "
        f"torch thread) started together; learner-steps/s = {rep['sb3_processes']} x steps / wall until the "
        f"last exits: {_fmt(sb3['steps_per_s'])} (CPU: {_fmt(sb3['steps_per_cpu_s'])} per "
        f"CPU-s), peak RSS {_fmt(sb3['max_rss_mb'])} MB per process. Measured once per repeat and paired with "
        "every R of that repeat (> 1: ours is faster).",
        [
            ("engine", lambda row: row["engine"]),
            ("R", lambda row: str(row["replicas"])),
            ("learners", lambda row: str(row["learners"])),
            ("ours wall s", lambda row: _fmt(row["figures"]["seconds"], 1)),
            ("ours learner-steps/s", lambda row: _fmt(row["figures"]["steps_per_s"])),
            ("ours learner-steps/CPU-s", lambda row: _fmt(row["figures"]["steps_per_cpu_s"])),
            ("ours peak RSS MB", lambda row: _fmt(row["figures"]["max_rss_mb"])),
            ("SB3 learner-steps/s", lambda row: _fmt(sb3["steps_per_s"])),
            ("ours / SB3 (wall)", lambda row: _x(row["ours_over_sb3"])),
            ("ours / SB3 (CPU)", lambda row: _x(row["ours_over_sb3_cpu"])),
        ],
        rep["rows"],
    )


def _tabular_table(res: Doc) -> list[str]:
    tab = res["tabular"]
    short, long = tab["steps"]
    paired = tab["baseline"] is not None
    against = (
        f" Baseline: the checkout `{tab['baseline']}`"
        + (f" (commit {tab['baseline_commit'][:12]})" if tab["baseline_commit"] else "")
        + ", its own `train.py` and package; baseline / ours: its seconds per step over ours', paired by "
        "repeat (> 1: ours is faster)."
        if paired
        else " No baseline was given (`--baseline DIR` runs an earlier checkout beside this one)."
    )
    columns: list[Column] = [
        ("mode", lambda row: row["mode"]),
        ("R", lambda row: str(row["replicas"])),
        ("ours s / 1k steps", lambda row: _fmt(row["ours"]["seconds_per_1k_steps"], 2)),
        ("ours CPU s / 1k steps", lambda row: _fmt(row["ours"]["cpu_seconds_per_1k_steps"], 2)),
        ("ours agent-steps/s", lambda row: _fmt(row["ours"]["agent_steps_per_s"])),
        ("ours peak RSS MB", lambda row: _fmt(row["ours"]["max_rss_mb"])),
    ]
    if paired:
        columns += [
            ("baseline s / 1k steps", lambda row: _fmt(row["baseline"]["seconds_per_1k_steps"], 2)),
            ("baseline agent-steps/s", lambda row: _fmt(row["baseline"]["agent_steps_per_s"])),
            ("baseline / ours (wall)", lambda row: _x(row["speedup"])),
            ("(CPU)", lambda row: _x(row["speedup_cpu"])),
        ]
    return _part(
        f"## 7. The study's tabular jobs: R replicas of a {tab['agents']}-agent SARSA team in one process, "
        "marginal cost per step",
        f"{_machine_line(res, tab['load'])} Settings: `python train.py agent=sarsa env={tab['env']} mode=M "
        f"replicas.seeds=R total_steps=T eval_every={tab['eval_every']} checkpoint_every=T progress=false`; the "
        f"marginal cost is the wall (CPU) time of T = {long:,} minus that of T = {short:,}, per 1,000 joint "
        f"steps (start-up, config writing and the final checkpoint cancel); agent-steps/s = "
        f"{long - short:,} x R x {tab['agents']} / that difference.{against}",
        columns,
        tab["rows"],
        label_column=True,
    )


TABLES = {  # a section's part of the table, in table order
    "env": _env_table,
    "training": _training_table,
    "team": _team_table,
    "update": _update_table,
    "lone": _lone_table,
    "replicas": _replicas_table,
    "tabular": _tabular_table,
}


def render_markdown(res: Doc) -> str:
    """The table of a benchmark's document: a header, then one part per measured section."""
    s, m = res["settings"], res["machine"]
    load = (
        f"; load average (1 min) at start {m['load']['start'][0]:.2f}, at end {m['load']['end'][0]:.2f}"
        if m["load"]["start"] and m["load"]["end"]
        else ""
    )
    lines = [
        f"# dqn_transfer benchmark ({s['profile']})",
        "",
        f"Method: {res['method']} R = {s['repeats']}, seed {s['seed']}, torch threads {s['threads']} unless stated.",
        "",
        f"Machine: {m['cpu_model']}, {m['cpus_available']} CPU(s) available ({m['cpu_count']} total), "
        f"torch {m['torch']} (default {m['torch_default_threads']} threads), SB3 {m['stable_baselines3']}, "
        f"gymnasium {m['gymnasium']}, PettingZoo {m['pettingzoo']}, Python {m['python']}{load}.",
    ]
    for section, table in TABLES.items():
        if section in res:
            lines += ["", *table(res)]
    lines.append("")
    return "\n".join(lines)
