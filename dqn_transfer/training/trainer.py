"""The training loop: config -> games + learners -> loop -> logs, evaluations, checkpoints.

This is the only module that knows the game, the learners, the checkpoint files and the logger.
One *step* is one joint environment step: every live agent acts once. A run may batch R independent
*replicas* (``replicas.seeds`` x ``replicas.maps``): R games stepped in lockstep and one batched
learner, each replica otherwise a complete run of its own (:class:`Replica`, its own run directory).
:meth:`Trainer.run` reads top to bottom:

1. act epsilon-greedily for every live agent (one batched forward for all agents of all replicas);
2. step the games, hand the joint transition to the learner (which stores it and trains);
3. at a replica's episode end: log per-agent and team statistics, exchange knowledge if due, reset;
4. every ``eval_every`` steps: greedy evaluation on separately seeded episodes -> ``metrics.jsonl``,
   and to TensorBoard with a picture of its first episode and the agents' Q-values there;
5. every ``LOG_EVERY`` steps: losses, Q means, epsilon and speed to TensorBoard and the progress bar;
6. every ``checkpoint_every`` steps, and when a signal asks to stop: a checkpoint of every replica.

A checkpoint holds the episode in progress (the game's state, the episode's running sums), so a
resumed run replays exactly what the uninterrupted run would have, from any step.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import signal
import sys
import threading
import time
import warnings
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from dqn_transfer.agents import Team, Transition, UpdateStats, joined, linear_schedule, make_replicas
from dqn_transfer.config import ConfigError, TrainConfig, replica_configs, to_plain, validate
from dqn_transfer.enums import Algorithm, Exchange
from dqn_transfer.envs import TreasureHuntGame, make_game
from dqn_transfer.evaluation.rollout import evaluate, team_return_of
from dqn_transfer.evaluation.watch import evaluation_views
from dqn_transfer.storage.checkpoint import (
    CheckpointError,
    atomic_write,
    atomic_write_all,
    encode_agent_checkpoint,
    encode_training_state,
    load_training_state,
)
from dqn_transfer.storage.run_dir import RunDir, existing_run_message
from dqn_transfer.timing import Stopwatch
from dqn_transfer.training.tensorboard import RunLogger
from dqn_transfer.transfer.capabilities import check_capabilities
from dqn_transfer.transfer.exchange import exchange_best, exchange_replay
from dqn_transfer.transfer.warm_start import apply_transfer, lineage_table

log = logging.getLogger("dqn_transfer.train")

LOG_EVERY = 200  # env steps between td_loss / q_mean / epsilon / sps points in TensorBoard


class Interrupted(Exception):
    """SIGINT or SIGTERM stopped the run between two steps, after it wrote its checkpoint there."""

    def __init__(self, signum: int, step: int, run_dir: Path) -> None:
        super().__init__(f"interrupted at step {step}")
        self.signum, self.step, self.run_dir = signum, step, Path(run_dir)

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 130 for SIGINT, 143 for SIGTERM."""
        return 128 + self.signum


class StopRequest:
    """Turns SIGINT (Ctrl-C) and SIGTERM (what SLURM sends before it kills a job) into a request the
    loop honours at the end of the step in progress, with a checkpoint that resumes exactly. A second
    Ctrl-C stops at once (``KeyboardInterrupt``). Signal handlers exist only in the main thread;
    elsewhere this is inert.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._previous = {signum: signal.signal(signum, self._handle) for signum in self.SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)

    def _handle(self, signum: int, frame) -> None:
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum
        log.warning(
            "%s received: stopping after this step, with a checkpoint%s",
            signal.Signals(signum).name,
            " (Ctrl-C again to stop at once)" if signum == signal.SIGINT else "",
        )


def build_game(config: TrainConfig, source_task: bool = False) -> TreasureHuntGame:
    """The game of ``config.env``; ``source_task`` gives the single-agent MDP of TreasureHunt-v0."""
    try:
        game = make_game(**dataclasses.asdict(config.env))
    except (ValueError, OSError) as err:
        raise ConfigError(f"env: {err}") from err
    return game.single_agent_game() if source_task else game


def exploration_steps(config: TrainConfig) -> int:
    return max(1, int(config.agent.exploration_fraction * config.total_steps))


def epsilons_at(config: TrainConfig, step: int, transferred: np.ndarray, duration: int) -> np.ndarray:
    """Per-agent exploration rate: linear decay over ``duration`` steps, from ``transfer.epsilon_start``
    for transferred agents."""
    return np.array(
        [
            linear_schedule(
                config.transfer.epsilon_start if is_transferred else config.agent.eps_start,
                config.agent.eps_end,
                duration,
                step,
            )
            for is_transferred in transferred
        ]
    )


@dataclass
class Counters:
    """What the loop needs, beyond the learner, to continue exactly where it stopped."""

    step: int = 0
    episodes: int = 0
    evaluations: int = 0
    next_checkpoint: int = 0
    exploration_steps: int = 1  # epsilon's decay horizon, fixed when the run starts (resume may extend total_steps)
    env_rng_state: dict = field(default_factory=dict)


class EpisodeStats:
    """Running sums of the episode in progress, and the recent team returns the progress bar shows."""

    def __init__(self, num_agents: int):
        self.returns = np.zeros(num_agents)
        self.lengths = np.zeros(num_agents, dtype=np.int64)
        self.traps = 0
        self.team_return = 0.0
        self.recent_team_returns: deque[float] = deque(maxlen=20)

    def add(self, transition: Transition, traps: np.ndarray, reward_mode) -> None:
        self.returns += transition.rewards
        self.lengths += transition.live
        self.traps += int(traps.sum())
        self.team_return += team_return_of(transition.rewards[transition.live], reward_mode)

    def reset(self) -> None:
        self.recent_team_returns.append(self.team_return)
        self.returns[:] = 0.0
        self.lengths[:] = 0
        self.traps = 0
        self.team_return = 0.0

    def state_dict(self) -> dict[str, Any]:
        return {
            "returns": self.returns.tolist(),
            "lengths": self.lengths.tolist(),
            "traps": self.traps,
            "team_return": self.team_return,
            "recent_team_returns": list(self.recent_team_returns),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.returns[:] = state["returns"]
        self.lengths[:] = state["lengths"]
        self.traps, self.team_return = int(state["traps"]), float(state["team_return"])
        self.recent_team_returns.extend(state["recent_team_returns"])


class Replica:
    """One independent run of the batch: its config (own seed and map), run directory, games,
    counters, episode in progress, exchange window and logs. ``learner`` is its team's view of the
    batched learner. With no replicas the trainer has one, in the run directory itself."""

    def __init__(
        self,
        index: int,
        config: TrainConfig,
        run_dir: Path,
        game: TreasureHuntGame,
        learner: Team,
        source: Path | Sequence[Path] | None,
    ) -> None:
        self.index, self.config, self.run_dir = index, config, RunDir(run_dir)
        self.game, self.eval_game, self.learner, self.source = game, game.replica(), learner, source
        k = game.num_agents
        self.rows = slice(index * k, (index + 1) * k)
        self.counters = Counters(next_checkpoint=config.checkpoint_every, exploration_steps=exploration_steps(config))
        self.transfer_info: dict[str, Any] | None = None
        self.last_eval: dict[str, float] = {}
        self.last_eval_step: int | None = None  # step of the last line in metrics.jsonl
        # Team knowledge exchange window (saved with checkpoints, so a resumed run exchanges the same):
        self.window_returns: list[np.ndarray] = []  # per-agent episodic returns since the last exchange
        self.shared_transitions: list[Transition] = []  # shared_replay: the window's transitions
        self.episode = EpisodeStats(k)
        self.window: list[UpdateStats] = []  # update statistics since the last training-curve point
        self.env_rng = np.random.default_rng([config.seed, 17])
        self.obs: np.ndarray | None = None
        self.episode_state: dict[str, Any] | None = None  # a mid-episode checkpoint's game, until the loop starts
        self.logger: RunLogger | None = None
        self.plain_config = to_plain(config)  # as JSON data, for logs and checkpoint meta (a config never changes)

    @property
    def transferred(self) -> np.ndarray:
        """Which agents started from the transfer source."""
        flags = np.zeros(self.game.num_agents, dtype=bool)
        if self.transfer_info is not None:
            flags[self.transfer_info["targets"]] = True
        return flags

    def epsilon(self, step: int) -> np.ndarray:
        return epsilons_at(self.config, step, self.transferred, self.counters.exploration_steps)

    def start_episodes(self) -> None:
        """The episode the loop continues: a checkpoint's, or a fresh one."""
        if self.counters.env_rng_state:  # resumed: continue the episode-reset stream where it stopped
            self.env_rng.bit_generator.state = self.counters.env_rng_state
        if self.episode_state is not None:
            self.obs = self.game.load_state_dict(self.episode_state["game"], self.env_rng)
            self.episode.load_state_dict(self.episode_state["stats"])
        else:
            self.obs = self.game.reset(self.env_rng)


class Trainer:
    """Owns one run directory: builds everything, runs the loop, writes every artefact.

    With ``replicas.seeds`` x ``replicas.maps`` > 1, the run directory holds one complete run
    directory per replica (``seed_<s>`` or ``seed_<s>-map_<m>``), and one batched learner trains
    them all in lockstep. ``sources`` are the checkpoints a ``transfer.enabled`` run starts its target
    agents from, per replica one for all targets or a list with one per target (found or pretrained by
    :func:`dqn_transfer.sources.resolve.transfer_sources`);
    ``source_task`` trains the single-agent source task of the map instead of the team.
    """

    def __init__(
        self,
        config: TrainConfig,
        run_dir: Path,
        *,
        sources: Sequence[Path | Sequence[Path]] | None = None,
        source_task: bool = False,
    ):
        validate(config)
        self.config = config
        self.run_dir = RunDir(run_dir)
        self.source_task = source_task
        self.algorithm = Algorithm(config.agent.algorithm)
        configs = replica_configs(config)
        games = [build_game(c, source_task) for c in configs]
        first = games[0]
        self.learner = make_replicas(
            config.agent,
            first.num_agents,
            first.obs_layout(),
            first.num_actions,
            seeds=[c.seed for c in configs],
            device=config.device,
            threads=config.threads,
        )
        check_capabilities(config, self.learner, warm_start=config.transfer.enabled and not source_task)
        sources = list(sources) if sources is not None else [None] * len(configs)
        self.replicas = [
            Replica(
                r,
                c,
                self.run_dir.path if len(configs) == 1 else self.run_dir.path / replica_name(c, config),
                game,
                self.learner.replica(r),
                source,
            )
            for r, (c, game, source) in enumerate(zip(configs, games, sources))
        ]
        # Time spent outside the loop proper (what a benchmark subtracts to compare with bare loops).
        self.evaluation_time, self.checkpoint_time = Stopwatch(), Stopwatch()

    @property
    def step(self) -> int:
        return self.replicas[0].counters.step  # the replicas run in lockstep

    # ------------------------------------------------------------------ setup
    def prepare(self) -> None:
        """Resume, or start fresh (with transfer if asked); refuses to overwrite another run."""
        held = [rep.run_dir for rep in self.replicas if rep.run_dir.has_run()]
        if self.config.resume:
            missing = [str(rep.run_dir) for rep in self.replicas if not rep.run_dir.has_run()]
            if missing:
                raise ConfigError(
                    f"resume=true but {missing[0]} holds no {self.run_dir.training_state.name}: pass the run "
                    "directory to resume with hydra.run.dir=PATH"
                )
            for rep in self.replicas:
                self._load_state(rep)
            steps = sorted({rep.counters.step for rep in self.replicas})
            if len(steps) > 1:
                raise CheckpointError(
                    f"{self.run_dir}: the replicas' checkpoints are at different steps {steps} "
                    "(a checkpoint write was cut short); resume each replica on its own"
                )
            return
        if held:
            raise ConfigError(existing_run_message(held[0]))
        if self.config.transfer.enabled and not self.source_task:
            for rep in self.replicas:
                if rep.source is None:
                    raise ConfigError(
                        "transfer.enabled: the trainer needs the source checkpoint "
                        "(dqn_transfer.sources.resolve.transfer_sources finds or pretrains it)"
                    )
                rep.transfer_info = apply_transfer(rep.config, rep.learner, rep.game, rep.source)

    def _write_replica_configs(self) -> None:
        """Each replica's own composed config, where the readers of a run directory look for it."""
        if len(self.replicas) == 1:
            return
        for rep in self.replicas:
            rep.run_dir.hydra_dir.mkdir(parents=True, exist_ok=True)
            atomic_write(rep.run_dir.config, OmegaConf.to_yaml(OmegaConf.structured(rep.config)).encode())
        # With the batch's own config: what resume=true on the batch directory continues with.
        index = {"replicas": [rep.run_dir.path.name for rep in self.replicas], "config": to_plain(self.config)}
        atomic_write(self.run_dir.replicas_index, (json.dumps(index, indent=2) + "\n").encode())

    # --------------------------------------------------------------------- loop
    def run(self) -> dict[str, Any]:
        """Train to ``total_steps`` (or continue a resumed run); returns a short summary.

        Raises :class:`Interrupted` when SIGINT or SIGTERM stopped it (at the end of the step in
        progress, after a checkpoint there).
        """
        with StopRequest() as stop, logging_redirect_tqdm():  # log lines print above the bar, never glued to it
            self.prepare()
            self.run_dir.path.mkdir(parents=True, exist_ok=True)
            self._write_replica_configs()
            try:
                for rep in self.replicas:
                    # Everything logged at the checkpoint's step came before it: purge only what came after.
                    rep.logger = RunLogger(
                        rep.run_dir.tensorboard,
                        rep.game.num_agents,
                        rep.plain_config,
                        purge_step=rep.counters.step + 1 if self.config.resume else None,
                    )
                return self._train(stop)
            finally:
                for rep in self.replicas:
                    if rep.logger is not None:
                        rep.logger.close()

    def _train(self, stop: StopRequest) -> dict[str, Any]:
        config, learner, replicas = self.config, self.learner, self.replicas
        for rep in replicas:
            if rep.transfer_info is not None and not config.resume:
                rep.logger.text("transfer/source", json.dumps(rep.transfer_info, indent=2))
                rep.logger.text("transfer/lineage", lineage_table(rep.transfer_info))
        if config.total_steps == 0:
            self.save_checkpoint()
            log.info("total_steps=0: wrote the initial checkpoints to %s", self.run_dir)
            return self._summary()
        for rep in replicas:
            if rep.counters.step % config.eval_every == 0 and rep.last_eval_step != rep.counters.step:
                self.run_evaluation(rep)  # step 0, or a resumed checkpoint's step whose eval was lost
            rep.start_episodes()
        shared_replay = config.transfer.exchange is Exchange.shared_replay
        bar = tqdm(
            total=config.total_steps,
            initial=self.step,
            disable=not config.progress,
            unit="step",
            dynamic_ncols=True,
            file=sys.stderr,
        )
        sps_clock, sps_step = time.perf_counter(), self.step
        while self.step < config.total_steps:
            # 1. act: one batched forward for every agent of every replica
            step = self.step
            epsilon = joined([rep.epsilon(step) for rep in replicas])
            live = joined([rep.game.live for rep in replicas])
            obs = joined([rep.obs for rep in replicas])
            actions = learner.act(obs, live, epsilon=epsilon)
            # 2. step the games and learn
            outcomes = [rep.game.step(actions[rep.rows]) for rep in replicas]
            step += 1
            next_obs, rewards, terminated, truncated = (joined([o[i] for o in outcomes]) for i in range(4))
            transition = Transition(obs, actions, rewards, next_obs, terminated, truncated, live)
            stats = learner.update(transition, step)
            for rep, outcome in zip(replicas, outcomes):
                rep.counters.step = step
                own = Transition(*(column[rep.rows] for column in transition))
                rep.window.append(UpdateStats(*(column[rep.rows] for column in stats)))
                if shared_replay:
                    rep.shared_transitions.append(own)
                rep.episode.add(own, outcome[4]["trap"], rep.game.reward_mode)
                rep.obs = own.next_obs
                # 3. episode end: log, exchange knowledge, start the next episode
                if rep.game.done:
                    self._end_episode(rep)
                    rep.obs = rep.game.reset(rep.env_rng)
            # 4. evaluation
            if step % config.eval_every == 0:
                for rep in replicas:
                    self.run_evaluation(rep)
            # 5. training curves and the progress bar
            if step % LOG_EVERY == 0 or step == config.total_steps:
                now = time.perf_counter()
                sps = (step - sps_step) / max(now - sps_clock, 1e-9)
                sps_clock, sps_step = now, step
                for rep in replicas:
                    self._log_training(rep, sps)
                recent = [r for rep in replicas for r in rep.episode.recent_team_returns]
                bar.set_postfix(
                    team_return=f"{np.mean(recent):.1f}" if recent else "-",
                    eps=f"{epsilon.mean():.2f}",
                    sps=f"{sps:.0f}",
                    refresh=False,
                )
                bar.update(step - bar.n)
            # 6. checkpoint when due, and at a signal (a checkpoint between two steps resumes exactly)
            if step >= replicas[0].counters.next_checkpoint or stop.signum is not None:
                self.save_checkpoint()
                for rep in replicas:
                    while rep.counters.next_checkpoint <= step:
                        rep.counters.next_checkpoint += config.checkpoint_every
                if stop.signum is not None:
                    bar.close()
                    raise Interrupted(stop.signum, step, self.run_dir.path)
        bar.close()
        for rep in replicas:
            if rep.last_eval_step != self.step:  # not twice when resuming a finished run
                self.run_evaluation(rep)
        self.save_checkpoint()
        rep = replicas[0]
        log.info(
            "done: %d steps, %s episodes; last eval %s; checkpoints in %s; watch with `tensorboard --logdir %s`",
            self.step,
            "/".join(str(r.counters.episodes) for r in replicas),
            rep.last_eval if len(replicas) == 1 else f"(mean of {len(replicas)} replicas) {self._mean_last_eval()}",
            rep.run_dir.checkpoints if len(replicas) == 1 else f"{self.run_dir}/*/checkpoints",
            rep.run_dir.tensorboard if len(replicas) == 1 else self.run_dir,
        )
        return self._summary()

    def _end_episode(self, rep: Replica) -> None:
        """Log the finished episode and exchange knowledge when due (before the reset)."""
        counters, config = rep.counters, rep.config
        counters.episodes += 1
        self._log_episode(rep)
        rep.window_returns.append(rep.episode.returns.copy())
        rep.episode.reset()
        if config.transfer.exchange is not Exchange.none and counters.episodes % config.transfer.exchange_every == 0:
            self._exchange(rep)

    def _mean_last_eval(self) -> dict[str, float]:
        return {
            key: float(np.mean([rep.last_eval[key] for rep in self.replicas])) for key in self.replicas[0].last_eval
        }

    def _summary(self) -> dict[str, Any]:
        lone = self.replicas[0]
        return {
            "step": self.step,
            "episodes": lone.counters.episodes,
            # A lone run's last evaluation; with replicas the mean over them, each replica's in "replicas".
            "last_eval": lone.last_eval if len(self.replicas) == 1 else self._mean_last_eval(),
            "replicas": [
                {
                    "run_dir": str(rep.run_dir),
                    "seed": rep.config.seed,
                    "map_seed": rep.config.env.map_seed,
                    "episodes": rep.counters.episodes,
                    "last_eval": rep.last_eval,
                }
                for rep in self.replicas
            ],
            # Seconds spent evaluating and checkpointing (wall, CPU): not part of the loop proper.
            "overhead": {
                "wall": self.evaluation_time.wall + self.checkpoint_time.wall,
                "cpu": self.evaluation_time.cpu + self.checkpoint_time.cpu,
            },
        }

    @staticmethod
    def _log_episode(rep: Replica) -> None:
        logger, episode, step, game = rep.logger, rep.episode, rep.counters.step, rep.game
        logger.agent_scalars("episodic_return", episode.returns, step)
        logger.agent_scalars("episodic_length", episode.lengths, step)
        logger.scalar("team/return", episode.team_return, step)
        logger.scalar("team/treasures_collected", game.treasures_collected, step)
        logger.scalar("team/trap_rate", episode.traps / game.num_agents, step)

    @staticmethod
    def _log_training(rep: Replica, sps: float) -> None:
        logger, window, step = rep.logger, rep.window, rep.counters.step
        with warnings.catch_warnings():  # all-NaN columns (no update yet) are expected and skipped
            warnings.simplefilter("ignore", RuntimeWarning)
            if window:
                logger.agent_scalars(
                    "td_loss", np.nanmean(np.asarray([s.td_loss for s in window], dtype=float), axis=0), step
                )
                logger.agent_scalars(
                    "q_mean", np.nanmean(np.asarray([s.q_mean for s in window], dtype=float), axis=0), step
                )
        logger.scalar("train/epsilon", float(rep.epsilon(step).mean()), step)
        logger.scalar("train/sps", sps, step)
        rep.window = []

    @staticmethod
    def _exchange(rep: Replica) -> None:
        transfer = rep.config.transfer
        if transfer.exchange is Exchange.best:
            best = exchange_best(rep.learner, np.asarray(rep.window_returns), transfer.exchange_tau)
            rep.logger.scalar("team/exchange_best_agent", best, rep.counters.step)
        else:
            exchange_replay(rep.learner, rep.shared_transitions)
            rep.shared_transitions.clear()
        rep.window_returns.clear()

    # --------------------------------------------------------------- evaluation
    def run_evaluation(self, rep: Replica) -> None:
        with self.evaluation_time:
            step = rep.counters.step
            picture, q_values, first = evaluation_views(
                rep.learner, rep.eval_game, rep.config.seed, rep.counters.evaluations
            )
            result = evaluate(
                rep.learner,
                rep.eval_game,
                rep.config.eval_episodes,
                rep.config.seed,
                rep.counters.evaluations,
                first=first,
            )
            rep.counters.evaluations += 1
            rep.last_eval = result
            rep.last_eval_step = step
            record: dict[str, Any] = {
                "step": step,
                **result,
                "episodes": rep.counters.episodes,
                "epsilon": float(rep.epsilon(step).mean()),
                "wall_time": time.time(),
            }
            if step == 0 and rep.transfer_info is not None:
                record["transfer_source"] = rep.transfer_info
            with rep.run_dir.metrics.open("a") as stream:
                stream.write(json.dumps(record) + "\n")
            rep.logger.scalar("eval/team_return", result["team_return"], step)
            rep.logger.scalar("eval/success_rate", result["success_rate"], step)
            rep.logger.scalar("eval/trap_rate", result["trap_rate"], step)
            rep.logger.evaluation_views(picture, q_values, step)
        log.info(
            "eval step %d%s: team_return %.1f success_rate %.2f trap_rate %.2f",
            step,
            f" {rep.run_dir.path.name}" if len(self.replicas) > 1 else "",
            result["team_return"],
            result["success_rate"],
            result["trap_rate"],
        )

    # ------------------------------------------------------------- checkpoints
    def agent_meta(self, rep: Replica, index: int, plain: dict[str, Any]) -> dict[str, Any]:
        """What ``agent_{index}.safetensors`` says about itself (``plain``: the config as JSON data)."""
        game = rep.game
        return {
            "algorithm": self.algorithm.value,
            "agent_index": index,
            "obs_layout": [[name, size] for name, size in game.obs_layout()],
            "num_actions": game.num_actions,
            "network": rep.learner.network_meta(),
            # The map as played: ``make_game(**meta["env"])`` rebuilds it from the layout alone.
            "env": {
                **plain["env"],
                "layout": game.map.layout,
                "layout_file": None,
                "size": game.size,
                "num_treasures": game.num_treasures,
                "num_traps": game.map.num_traps,
                "num_agents": game.map.num_agents,
                "complexity": None,
                "map_seed": None,
            },
            "mode": plain["env"]["mode"],
            "source_task": self.source_task,
            "agent": plain["agent"],
            "seed": rep.config.seed,
            "steps": rep.counters.step,
            "episodes": rep.counters.episodes,
            "last_eval": rep.last_eval,
            "transfer": rep.transfer_info,
        }

    def save_checkpoint(self) -> None:
        """Every replica's agent files (for sharing) and resume state, which alone is read on resume.

        All files are written before any replaces its predecessor, the resume states last: a failed
        write leaves the previous checkpoints whole.
        """
        with self.checkpoint_time:
            agent_files: dict[Path, bytes] = {}
            state_files: dict[Path, bytes] = {}
            for rep in self.replicas:
                rep.counters.env_rng_state = rep.env_rng.bit_generator.state
                plain = rep.plain_config
                arrays: dict[str, np.ndarray] = {}
                for i in range(rep.game.num_agents):
                    tensors = rep.learner.agent_tensors(i)
                    agent_files[rep.run_dir.agent_checkpoint(i)] = encode_agent_checkpoint(
                        tensors, self.agent_meta(rep, i, plain)
                    )
                    arrays.update({f"agent_{i}/{name}": t for name, t in tensors.items()})
                learner_arrays, learner_meta = rep.learner.training_state()
                arrays.update({f"learner/{name}": a for name, a in learner_arrays.items()})
                arrays["exchange/returns"] = np.asarray(rep.window_returns, dtype=np.float64).reshape(
                    -1, rep.game.num_agents
                )
                for name, column in zip(Transition._fields, zip(*rep.shared_transitions)):
                    arrays[f"exchange/{name}"] = np.stack(column)
                meta = {
                    "counters": rep.counters.__dict__,
                    "learner": learner_meta,
                    "last_eval": rep.last_eval,
                    "transfer": rep.transfer_info,
                    "obs_layout": [[name, size] for name, size in rep.game.obs_layout()],
                    "algorithm": self.algorithm.value,
                    "config": plain,  # what resume=true continues with
                    "layout": rep.game.map.layout,  # the map itself: a layout file may have changed since
                    # The episode in progress (None before the loop starts or after it ends).
                    "episode": None
                    if rep.obs is None or rep.game.done
                    else {"game": rep.game.state_dict(), "stats": rep.episode.state_dict()},
                }
                state_files[rep.run_dir.training_state] = encode_training_state(arrays, meta)
            atomic_write_all({**agent_files, **state_files})

    def _load_state(self, rep: Replica) -> None:
        arrays, meta = load_training_state(rep.run_dir.training_state)
        expected_layout = [[name, size] for name, size in rep.game.obs_layout()]
        if meta.get("obs_layout") != expected_layout or meta.get("algorithm") != self.algorithm.value:
            raise CheckpointError(
                f"{rep.run_dir.checkpoints}: the run was made with algorithm {meta.get('algorithm')} and obs layout "
                f"{meta.get('obs_layout')}; this config gives {self.algorithm.value} and {expected_layout}"
            )
        if meta.get("layout") != rep.game.map.layout:
            raise CheckpointError(
                f"{rep.run_dir.checkpoints}: the run was trained on another map:\n"
                f"{meta.get('layout')}\nthis config gives\n{rep.game.map.layout}"
            )
        for i in range(rep.game.num_agents):
            prefix = f"agent_{i}/"
            rep.learner.load_agent_tensors(i, {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)})
        rep.learner.load_training_state(
            {k[len("learner/") :]: v for k, v in arrays.items() if k.startswith("learner/")}, meta["learner"]
        )
        rep.counters = Counters(**meta["counters"])
        rep.window_returns = list(arrays.get("exchange/returns", []))
        if "exchange/obs" in arrays:
            rep.shared_transitions = [
                Transition(*fields) for fields in zip(*(arrays[f"exchange/{name}"] for name in Transition._fields))
            ]
        rep.last_eval = meta["last_eval"]
        rep.transfer_info = meta["transfer"]
        rep.episode_state = meta.get("episode")  # None at an episode end (and in older checkpoints)
        self._truncate_metrics(rep, rep.counters.evaluations)
        log.info("resumed %s at step %d (episode %d)", rep.run_dir, rep.counters.step, rep.counters.episodes)

    @staticmethod
    def _truncate_metrics(rep: Replica, evaluations: int) -> None:
        """Keep the evaluations the checkpoint counted; the killed run's later ones will be redone.

        By count, not by step: a line at the checkpoint's step may be one the checkpoint does not
        know about (written after it, by a run killed before its next checkpoint).
        """
        if not rep.run_dir.metrics.exists():
            return
        lines = [line for line in rep.run_dir.metrics.read_text().splitlines() if line.strip()][:evaluations]
        atomic_write(rep.run_dir.metrics, "".join(line + "\n" for line in lines).encode())
        rep.last_eval_step = json.loads(lines[-1])["step"] if lines else None


def replica_name(replica: TrainConfig, config: TrainConfig) -> str:
    """``seed_<s>``, and ``-map_<m>`` when the batch varies the map too."""
    return f"seed_{replica.seed}" + (f"-map_{replica.env.map_seed}" if config.replicas.maps > 1 else "")


def train(
    config: TrainConfig,
    run_dir: Path,
    *,
    sources: Sequence[Path | Sequence[Path]] | None = None,
    source_task: bool = False,
) -> dict[str, Any]:
    """Run (or resume) one training run (or batch of replicas) into ``run_dir``; returns a short summary."""
    return Trainer(config, run_dir, sources=sources, source_task=source_task).run()
