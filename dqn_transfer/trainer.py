"""The training loop: config -> game + learners -> loop -> logs, evaluations, checkpoints.

This is the only module that knows the game, the learners, the checkpoint files and the logger.
One *step* is one joint environment step: every live agent acts once. :meth:`Trainer.run` reads top
to bottom:

1. act epsilon-greedily for every live agent (one batched forward for all K agents);
2. step the game, hand the joint transition to the learner (which stores it and trains);
3. at an episode end: log per-agent and team statistics, exchange knowledge if due, checkpoint if
   due, reset the game;
4. every ``eval_every`` steps: greedy evaluation on separately seeded episodes -> ``metrics.jsonl``;
5. every ``LOG_EVERY`` steps: losses, Q means, epsilon and speed to TensorBoard and the progress bar.

Checkpoints sit on episode boundaries (the first after every ``checkpoint_every`` steps), so a
resumed run replays exactly what the uninterrupted run would have (the last one, at ``total_steps``,
may not: extending a finished run starts a fresh episode).
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from dqn_transfer.agents import Transition, UpdateStats, linear_schedule, make_learner
from dqn_transfer.checkpoint import (
    CheckpointError,
    atomic_write,
    atomic_write_all,
    encode_agent_checkpoint,
    encode_training_state,
    load_training_state,
)
from dqn_transfer.config import ConfigError, TrainConfig, to_plain, validate
from dqn_transfer.enums import Algorithm, Device, Exchange
from dqn_transfer.envs import TreasureHuntGame, make_game
from dqn_transfer.exchange import exchange_best, exchange_replay
from dqn_transfer.logging import RunLogger
from dqn_transfer.rollout import evaluate, team_return_of
from dqn_transfer.run_dir import RunDir, existing_run_message
from dqn_transfer.timing import Stopwatch
from dqn_transfer.warm_start import apply_transfer

log = logging.getLogger("dqn_transfer.train")

LOG_EVERY = 200  # env steps between td_loss / q_mean / epsilon / sps points in TensorBoard


class Interrupted(Exception):
    """SIGINT or SIGTERM stopped the run at an episode end, after it wrote its checkpoint there."""

    def __init__(self, signum: int, step: int, run_dir: Path) -> None:
        super().__init__(f"interrupted at step {step}")
        self.signum, self.step, self.run_dir = signum, step, Path(run_dir)

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 130 for SIGINT, 143 for SIGTERM."""
        return 128 + self.signum


class StopRequest:
    """Turns SIGINT (Ctrl-C) and SIGTERM (what SLURM sends before it kills a job) into a request the
    loop honours at the next episode end, where a checkpoint resumes exactly. A second Ctrl-C stops at
    once (``KeyboardInterrupt``). Signal handlers exist only in the main thread; elsewhere this is inert.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> "StopRequest":
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
        log.warning("%s received: stopping at the next episode end, after a checkpoint%s",
                    signal.Signals(signum).name, " (Ctrl-C again to stop at once)" if signum == signal.SIGINT else "")


def build_game(config: TrainConfig, source_task: bool = False) -> TreasureHuntGame:
    """The game of ``config.env``; ``source_task`` gives the single-agent MDP of TreasureHunt-v0."""
    try:
        game = make_game(**dataclasses.asdict(config.env))
    except (ValueError, OSError) as err:
        raise ConfigError(f"env: {err}") from err
    return game.single_agent_game() if source_task else game


def resolve_device(device: Device, threads: int) -> str:
    torch.set_num_threads(threads)
    if device is Device.auto:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device is Device.cuda and not torch.cuda.is_available():
        raise ConfigError("device=cuda but no CUDA device is available here (use device=cpu or device=auto)")
    return device.value


def exploration_steps(config: TrainConfig) -> int:
    return max(1, int(config.agent.exploration_fraction * config.total_steps))


def epsilons_at(config: TrainConfig, step: int, transferred: np.ndarray, duration: int) -> np.ndarray:
    """Per-agent exploration rate: linear decay over ``duration`` steps, from ``transfer.epsilon_start``
    for transferred agents."""
    return np.array([
        linear_schedule(config.transfer.epsilon_start if is_transferred else config.agent.eps_start,
                        config.agent.eps_end, duration, step)
        for is_transferred in transferred
    ])


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
        self.traps += int(np.sum(traps))
        self.team_return += team_return_of(transition.rewards[transition.live], reward_mode)

    def reset(self) -> None:
        self.recent_team_returns.append(self.team_return)
        self.returns[:] = 0.0
        self.lengths[:] = 0
        self.traps = 0
        self.team_return = 0.0


class Trainer:
    """Owns one run directory: builds everything, runs the loop, writes every artefact.

    ``source`` is the checkpoint a ``transfer.enabled`` run starts its target agents from (found or
    pretrained by :func:`dqn_transfer.sources.transfer_source`); ``source_task`` trains the
    single-agent source task of the map instead of the team.
    """

    def __init__(self, config: TrainConfig, run_dir: Path, *, source: Path | None = None,
                 source_task: bool = False):
        validate(config)
        self.config = config
        self.run_dir = RunDir(run_dir)
        self.source = source
        self.source_task = source_task
        self.algorithm = Algorithm(config.agent.algorithm)
        self.device = resolve_device(config.device, config.threads)
        self.game = build_game(config, source_task)
        self.eval_game = self.game.replica()
        self.learner = make_learner(config.agent, self.game.num_agents, self.game.obs_layout(),
                                    self.game.num_actions, seed=config.seed, device=self.device)
        self.counters = Counters(next_checkpoint=config.checkpoint_every, exploration_steps=exploration_steps(config))
        self.transfer_info: dict[str, Any] | None = None
        self.last_eval: dict[str, float] = {}
        self.last_eval_step: int | None = None  # step of the last line in metrics.jsonl
        # Team knowledge exchange window (saved with checkpoints, so a resumed run exchanges the same):
        self.window_returns: list[np.ndarray] = []  # per-agent episodic returns since the last exchange
        self.shared_transitions: list[Transition] = []  # shared_replay: the window's transitions
        # Time spent outside the loop proper (what a benchmark subtracts to compare with bare loops).
        self.evaluation_time, self.checkpoint_time = Stopwatch(), Stopwatch()

    # ------------------------------------------------------------------ setup
    def prepare(self) -> None:
        """Resume, or start fresh (with transfer if asked); refuses to overwrite another run."""
        has_state = self.run_dir.has_run()
        if self.config.resume:
            if not has_state:
                raise ConfigError(
                    f"resume=true but {self.run_dir} holds no {self.run_dir.training_state.name}: pass the run directory "
                    "to resume with hydra.run.dir=PATH")
            self._load_state()
            return
        if has_state:
            raise ConfigError(existing_run_message(self.run_dir))
        if self.config.transfer.enabled and not self.source_task:
            if self.source is None:
                raise ConfigError("transfer.enabled: the trainer needs the source checkpoint "
                                  "(dqn_transfer.sources.transfer_source finds or pretrains it)")
            self.transfer_info = apply_transfer(self.config, self.learner, self.game, self.source)

    @property
    def transferred(self) -> np.ndarray:
        """Which agents started from the transfer source."""
        flags = np.zeros(self.game.num_agents, dtype=bool)
        if self.transfer_info is not None:
            flags[self.transfer_info["targets"]] = True
        return flags

    # --------------------------------------------------------------------- loop
    def run(self) -> dict[str, Any]:
        """Train to ``total_steps`` (or continue a resumed run); returns a short summary.

        Raises :class:`Interrupted` when SIGINT or SIGTERM stopped it (at the next episode end, after
        a checkpoint there).
        """
        with StopRequest() as stop, logging_redirect_tqdm():  # log lines print above the bar, never glued to it
            self.prepare()
            self.run_dir.path.mkdir(parents=True, exist_ok=True)
            logger = RunLogger(self.run_dir.tensorboard, self.game.num_agents, to_plain(self.config),
                               purge_step=self.counters.step if self.config.resume else None)
            try:
                return self._train(logger, stop)
            finally:
                logger.close()

    def _train(self, logger: RunLogger, stop: StopRequest) -> dict[str, Any]:
        config, game, learner, counters = self.config, self.game, self.learner, self.counters
        if self.transfer_info is not None and not config.resume:
            logger.text("transfer/source", json.dumps(self.transfer_info, indent=2))
        if config.total_steps == 0:
            self.save_checkpoint()
            log.info("total_steps=0: wrote the initial checkpoints to %s", self.run_dir.checkpoints)
            return self._summary()
        if counters.step % config.eval_every == 0 and self.last_eval_step != counters.step:
            self.run_evaluation(logger)  # step 0, or a resumed checkpoint's step whose eval was lost

        env_rng = np.random.default_rng([config.seed, 17])
        if counters.env_rng_state:  # resumed: continue the episode-reset stream where it stopped
            env_rng.bit_generator.state = counters.env_rng_state
        obs = game.reset(env_rng)
        episode = EpisodeStats(game.num_agents)
        window: list[UpdateStats] = []
        transferred = self.transferred
        bar = tqdm(total=config.total_steps, initial=counters.step, disable=not config.progress,
                   unit="step", dynamic_ncols=True, file=sys.stderr)
        sps_clock, sps_step = time.perf_counter(), counters.step
        while counters.step < config.total_steps:
            # 1. act
            epsilon = epsilons_at(config, counters.step, transferred, counters.exploration_steps)
            live = game.live
            actions = learner.act(obs, live, epsilon=epsilon)
            # 2. step the game and learn
            next_obs, rewards, terminated, truncated, info = game.step(actions)
            counters.step += 1
            transition = Transition(obs, actions, rewards, next_obs, terminated, truncated, live)
            window.append(learner.update(transition, counters.step))
            if config.transfer.exchange is Exchange.shared_replay:
                self.shared_transitions.append(transition)
            episode.add(transition, info["trap"], game.reward_mode)
            obs = next_obs
            # 3. episode end (and a signal's safe point: the checkpoint there resumes exactly)
            if game.done:
                self._end_episode(logger, episode, env_rng, checkpoint_now=stop.signum is not None)
                if stop.signum is not None:
                    bar.close()
                    raise Interrupted(stop.signum, counters.step, self.run_dir.path)
                obs = game.reset(env_rng)
            # 4. evaluation
            if counters.step % config.eval_every == 0:
                self.run_evaluation(logger)
            # 5. training curves and the progress bar
            if counters.step % LOG_EVERY == 0 or counters.step == config.total_steps:
                now = time.perf_counter()
                sps = (counters.step - sps_step) / max(now - sps_clock, 1e-9)
                sps_clock, sps_step = now, counters.step
                self._log_training(logger, window, epsilon, sps, counters.step)
                window = []
                recent = episode.recent_team_returns
                bar.set_postfix(team_return=f"{np.mean(recent):.1f}" if recent else "-",
                                eps=f"{epsilon.mean():.2f}", sps=f"{sps:.0f}", refresh=False)
                bar.update(counters.step - bar.n)
        bar.close()
        if self.last_eval_step != counters.step:  # not twice when resuming a finished run
            self.run_evaluation(logger)
        counters.env_rng_state = env_rng.bit_generator.state
        self.save_checkpoint()
        log.info("done: %d steps, %d episodes; last eval %s; checkpoints in %s; watch with "
                 "`tensorboard --logdir %s`", counters.step, counters.episodes, self.last_eval,
                 self.run_dir.checkpoints, self.run_dir.tensorboard)
        return self._summary()

    def _end_episode(self, logger: RunLogger, episode: EpisodeStats, env_rng: np.random.Generator,
                     checkpoint_now: bool = False) -> None:
        """Log the finished episode, exchange knowledge and checkpoint when due or asked (before the reset)."""
        counters, config = self.counters, self.config
        counters.episodes += 1
        self._log_episode(logger, episode, counters.step)
        self.window_returns.append(episode.returns.copy())
        episode.reset()
        if config.transfer.exchange is not Exchange.none and counters.episodes % config.transfer.exchange_every == 0:
            self._exchange(logger)
        if counters.step >= counters.next_checkpoint or checkpoint_now:
            counters.env_rng_state = env_rng.bit_generator.state
            self.save_checkpoint()
            while counters.next_checkpoint <= counters.step:
                counters.next_checkpoint += config.checkpoint_every

    def _summary(self) -> dict[str, Any]:
        return {
            "step": self.counters.step,
            "episodes": self.counters.episodes,
            "last_eval": self.last_eval,
            # Seconds spent evaluating and checkpointing (wall, CPU): not part of the loop proper.
            "overhead": {"wall": self.evaluation_time.wall + self.checkpoint_time.wall,
                         "cpu": self.evaluation_time.cpu + self.checkpoint_time.cpu},
        }

    def _log_episode(self, logger: RunLogger, episode: EpisodeStats, step: int) -> None:
        logger.agent_scalars("episodic_return", episode.returns, step)
        logger.agent_scalars("episodic_length", episode.lengths, step)
        logger.scalar("team/return", episode.team_return, step)
        logger.scalar("team/treasures_collected", self.game.treasures_collected, step)
        logger.scalar("team/trap_rate", episode.traps / self.game.num_agents, step)

    @staticmethod
    def _log_training(logger: RunLogger, window: list[UpdateStats], epsilon: np.ndarray, sps: float,
                      step: int) -> None:
        with warnings.catch_warnings():  # all-NaN columns (no update yet) are expected and skipped
            warnings.simplefilter("ignore", RuntimeWarning)
            if window:
                logger.agent_scalars("td_loss", np.nanmean(np.asarray([s.td_loss for s in window], dtype=float), axis=0), step)
                logger.agent_scalars("q_mean", np.nanmean(np.asarray([s.q_mean for s in window], dtype=float), axis=0), step)
        logger.scalar("train/epsilon", float(epsilon.mean()), step)
        logger.scalar("train/sps", sps, step)

    def _exchange(self, logger: RunLogger) -> None:
        if self.config.transfer.exchange is Exchange.best:
            best = exchange_best(self.learner, np.asarray(self.window_returns), self.config.transfer.exchange_tau)
            logger.scalar("team/exchange_best_agent", best, self.counters.step)
        else:
            exchange_replay(self.learner, self.shared_transitions)
            self.shared_transitions.clear()
        self.window_returns.clear()

    # --------------------------------------------------------------- evaluation
    def run_evaluation(self, logger: RunLogger) -> None:
        with self.evaluation_time:
            step = self.counters.step
            result = evaluate(self.learner, self.eval_game, self.config.eval_episodes, self.config.seed,
                              self.counters.evaluations)
            self.counters.evaluations += 1
            self.last_eval = result
            self.last_eval_step = step
            epsilon = epsilons_at(self.config, step, self.transferred, self.counters.exploration_steps)
            record: dict[str, Any] = {"step": step, **result, "episodes": self.counters.episodes,
                                      "epsilon": float(epsilon.mean()), "wall_time": time.time()}
            if step == 0 and self.transfer_info is not None:
                record["transfer_source"] = self.transfer_info
            with self.run_dir.metrics.open("a") as stream:
                stream.write(json.dumps(record) + "\n")
            logger.scalar("eval/team_return", result["team_return"], step)
            logger.scalar("eval/success_rate", result["success_rate"], step)
        log.info("eval step %d: team_return %.1f success_rate %.2f trap_rate %.2f", step,
                 result["team_return"], result["success_rate"], result["trap_rate"])

    # ------------------------------------------------------------- checkpoints
    def agent_meta(self, index: int, plain: dict[str, Any]) -> dict[str, Any]:
        """What ``agent_{index}.safetensors`` says about itself (``plain``: the config as JSON data)."""
        game = self.game
        return {
            "algorithm": self.algorithm.value,
            "agent_index": index,
            "obs_layout": [[name, size] for name, size in game.obs_layout()],
            "num_actions": game.num_actions,
            "network": self.learner.network_meta(),
            # The map as played: ``make_game(**meta["env"])`` rebuilds it from the layout alone.
            "env": {**plain["env"], "layout": game.map.layout, "layout_file": None,
                    "size": game.size, "num_treasures": game.num_treasures, "num_traps": game.map.num_traps,
                    "num_agents": game.map.num_agents, "complexity": None, "map_seed": None},
            "mode": plain["env"]["mode"],
            "source_task": self.source_task,
            "agent": plain["agent"],
            "seed": self.config.seed,
            "steps": self.counters.step,
            "episodes": self.counters.episodes,
            "last_eval": self.last_eval,
            "transfer": self.transfer_info,
        }

    def save_checkpoint(self) -> None:
        """The agent files (for sharing) and the resume state, which alone is read on resume.

        All files are written before any replaces its predecessor, the resume state last: a failed
        write leaves the previous checkpoint whole.
        """
        with self.checkpoint_time:
            plain = to_plain(self.config)
            files: dict[Path, bytes] = {}
            arrays: dict[str, np.ndarray] = {}
            for i in range(self.game.num_agents):
                tensors = self.learner.agent_tensors(i)
                files[self.run_dir.agent_checkpoint(i)] = encode_agent_checkpoint(tensors, self.agent_meta(i, plain))
                arrays.update({f"agent_{i}/{name}": t.numpy() for name, t in tensors.items()})
            learner_arrays, learner_meta = self.learner.training_state()
            arrays.update({f"learner/{name}": a for name, a in learner_arrays.items()})
            arrays["exchange/returns"] = np.asarray(self.window_returns, dtype=np.float64).reshape(-1, self.game.num_agents)
            for name, column in zip(Transition._fields, zip(*self.shared_transitions)):
                arrays[f"exchange/{name}"] = np.stack(column)
            meta = {
                "counters": self.counters.__dict__,
                "learner": learner_meta,
                "last_eval": self.last_eval,
                "transfer": self.transfer_info,
                "obs_layout": [[name, size] for name, size in self.game.obs_layout()],
                "algorithm": self.algorithm.value,
                "config": plain,  # what resume=true continues with
                "layout": self.game.map.layout,  # the map itself: a layout file may have changed since
            }
            files[self.run_dir.training_state] = encode_training_state(arrays, meta)
            atomic_write_all(files)

    def _load_state(self) -> None:
        arrays, meta = load_training_state(self.run_dir.training_state)
        expected_layout = [[name, size] for name, size in self.game.obs_layout()]
        if meta.get("obs_layout") != expected_layout or meta.get("algorithm") != self.algorithm.value:
            raise CheckpointError(
                f"{self.run_dir.checkpoints}: the run was made with algorithm {meta.get('algorithm')} and obs layout "
                f"{meta.get('obs_layout')}; this config gives {self.algorithm.value} and {expected_layout}")
        if meta.get("layout") != self.game.map.layout:
            raise CheckpointError(f"{self.run_dir.checkpoints}: the run was trained on another map:\n"
                                  f"{meta.get('layout')}\nthis config gives\n{self.game.map.layout}")
        for i in range(self.game.num_agents):
            prefix = f"agent_{i}/"
            self.learner.load_agent_tensors(i, {k[len(prefix):]: torch.from_numpy(v.copy())
                                                for k, v in arrays.items() if k.startswith(prefix)})
        self.learner.load_training_state({k[len("learner/"):]: v for k, v in arrays.items()
                                          if k.startswith("learner/")}, meta["learner"])
        self.counters = Counters(**meta["counters"])
        self.window_returns = list(arrays.get("exchange/returns", []))
        if "exchange/obs" in arrays:
            self.shared_transitions = [Transition(*fields) for fields in
                                       zip(*(arrays[f"exchange/{name}"] for name in Transition._fields))]
        self.last_eval = meta["last_eval"]
        self.transfer_info = meta["transfer"]
        self._truncate_metrics(self.counters.evaluations)
        log.info("resumed %s at step %d (episode %d)", self.run_dir, self.counters.step, self.counters.episodes)

    def _truncate_metrics(self, evaluations: int) -> None:
        """Keep the evaluations the checkpoint counted; the killed run's later ones will be redone.

        By count, not by step: the loop checkpoints *before* evaluating the same step, so a line at
        the checkpoint's step may be one the checkpoint does not know about.
        """
        if not self.run_dir.metrics.exists():
            return
        lines = [line for line in self.run_dir.metrics.read_text().splitlines() if line.strip()][:evaluations]
        atomic_write(self.run_dir.metrics, "".join(line + "\n" for line in lines).encode())
        self.last_eval_step = json.loads(lines[-1])["step"] if lines else None


def train(config: TrainConfig, run_dir: Path, *, source: Path | None = None, source_task: bool = False) -> dict[str, Any]:
    """Run (or resume) one training run into ``run_dir``; returns a short summary."""
    return Trainer(config, run_dir, source=source, source_task=source_task).run()
