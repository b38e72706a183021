"""The training loop: config -> game + learners -> loop -> logs, evaluations, checkpoints.

This is the only module that knows the game, the learners, the checkpoint files and the logger.
One *step* is one joint environment step: every live agent acts once.  The loop:

1. act epsilon-greedily for every live agent (one batched forward for all K agents);
2. step the game, hand the K transitions to the learner (which stores them and trains);
3. at an episode end: log per-agent and team statistics, reset the game;
4. every ``eval_every`` steps: greedy evaluation on separately seeded episodes -> ``metrics.jsonl``;
5. at the first episode end after every ``checkpoint_every`` steps: checkpoint.  Checkpoints sit on
   episode boundaries so that a resumed run replays exactly what the uninterrupted run would have
   (the last one, at ``total_steps``, may not: extending a finished run starts a fresh episode).
"""

from __future__ import annotations

import json
import logging
import math
import sys
import time
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from dqn_transfer.config import (
    ConfigError,
    Device,
    Exchange,
    TrainConfig,
    register_configs,
    to_plain,
    validate,
)

log = logging.getLogger("dqn_transfer.train")

TRAINING_STATE = "training_state.safetensors"
TRANSITION_FIELDS = ("obs", "actions", "rewards", "next_obs", "terminated", "truncated", "live")
LOG_EVERY = 200  # env steps between td_loss / q_mean / epsilon / sps points in TensorBoard


def make_game(env_cfg: dict[str, Any], source_task: bool = False):
    """The game of ``env_cfg``; ``source_task`` gives the single-agent MDP of TreasureHunt-v0."""
    from dqn_transfer.envs import make_game as make_env_game

    try:
        game = make_env_game(**env_cfg)
    except (ValueError, OSError) as err:
        raise ConfigError(f"env: {err}") from err
    return game.single_agent_game() if source_task else game


def resolve_device(device: Device, threads: int) -> str:
    import torch

    torch.set_num_threads(threads)
    if device is Device.auto:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device is Device.cuda and not torch.cuda.is_available():
        raise ConfigError("device=cuda but no CUDA device is available here (use device=cpu or device=auto)")
    return device.value


def existing_run_message(run_dir: Path) -> str:
    return f"{run_dir} already holds a run; pass resume=true to continue it or choose another hydra.run.dir"


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
    """Running per-episode sums and the recent history shown in the progress bar."""

    def __init__(self, num_agents: int):
        self.returns = np.zeros(num_agents)
        self.lengths = np.zeros(num_agents, dtype=np.int64)
        self.traps = 0
        self.recent_team_returns: deque[float] = deque(maxlen=20)

    def add(self, rewards: np.ndarray, live_before: np.ndarray, traps: np.ndarray) -> None:
        self.returns += rewards
        self.lengths += live_before
        self.traps += int(np.sum(traps))

    def reset(self) -> None:
        self.returns[:] = 0.0
        self.lengths[:] = 0
        self.traps = 0


def team_return_of(rewards: np.ndarray, reward_mode: str) -> float:
    """Team return of one step: the sum of the agents' own rewards (not K times it in team mode)."""
    return float(rewards.max() if reward_mode == "team" and rewards.size else rewards.sum())


def evaluate(learner, game, episodes: int, seed: int, evaluation: int) -> dict[str, float]:
    """Greedy episodes, each seeded from (seed, evaluation, episode): independent of training history."""
    team_returns, success, traps, lengths = [], [], [], []
    num_agents = game.num_agents
    reward_mode = game.reward_mode
    for episode in range(episodes):
        obs = game.reset(np.random.default_rng([seed, 1_000_003, evaluation, episode]))
        team_return, length, trapped = 0.0, 0, 0
        while not game.done:
            live_before = game.live.copy()
            actions = learner.act(obs, live_before, epsilon=0.0, greedy=True)
            obs, rewards, _, _, info = game.step(actions)
            team_return += team_return_of(rewards[live_before], reward_mode)
            trapped += int(np.sum(info["trap"]))
            length += 1
        team_returns.append(team_return)
        success.append(game.treasures_collected / game.num_treasures)
        traps.append(trapped / num_agents)
        lengths.append(length)
    return {
        "team_return": float(np.mean(team_returns)),
        "success_rate": float(np.mean(success)),
        "trap_rate": float(np.mean(traps)),
        "episode_length": float(np.mean(lengths)),
    }


def exploration_steps(config: TrainConfig) -> int:
    return max(1, int(config.agent.exploration_fraction * config.total_steps))


def epsilons_at(config: TrainConfig, step: int, transferred: np.ndarray, duration: int) -> np.ndarray:
    """Per-agent exploration rate: linear decay over ``duration`` steps, from ``transfer.epsilon_start``
    for transferred agents."""
    from dqn_transfer.agents.schedules import linear_schedule

    return np.array([
        linear_schedule(config.transfer.epsilon_start if is_transferred else config.agent.eps_start,
                        config.agent.eps_end, duration, step)
        for is_transferred in transferred
    ])


class Trainer:
    """Owns one run directory: builds everything, runs the loop, writes every artefact."""

    def __init__(self, config: TrainConfig, run_dir: Path, *, source_task: bool = False,
                 launch_dir: Path | None = None):
        validate(config)
        self.config = config
        self.plain = to_plain(config)
        self.run_dir = Path(run_dir)
        self.launch_dir = Path(launch_dir) if launch_dir is not None else Path.cwd()
        self.source_task = source_task
        self.checkpoint_dir = self.run_dir / "checkpoints"
        self.metrics_path = self.run_dir / "metrics.jsonl"
        self.device = resolve_device(config.device, config.threads)
        self.game = make_game(self.plain["env"], source_task)
        self.eval_game = self.game.replica()
        from dqn_transfer.agents import make_learner

        self.learner = make_learner(self.plain["agent"], self.game.num_agents, self.game.obs_layout(),
                                    self.game.num_actions, seed=config.seed, device=self.device)
        self.counters = Counters(next_checkpoint=config.checkpoint_every, exploration_steps=exploration_steps(config))
        self.transfer_info: dict[str, Any] | None = None
        self.last_eval: dict[str, float] = {}
        self.last_eval_step: int | None = None  # step of the last line in metrics.jsonl
        # Team knowledge exchange window (saved with checkpoints, so a resumed run exchanges the same):
        self.window_returns: list[np.ndarray] = []  # per-agent episodic returns since the last exchange
        self.shared_transitions: list[tuple] = []  # shared_replay: the window's transitions

    # ------------------------------------------------------------------ setup
    def prepare(self) -> None:
        """Resume, or start fresh (with transfer if asked); refuses to overwrite another run."""
        has_state = (self.checkpoint_dir / TRAINING_STATE).exists()
        if self.config.resume:
            if not has_state:
                raise ConfigError(
                    f"resume=true but {self.run_dir} holds no {TRAINING_STATE}: pass the run directory "
                    "to resume with hydra.run.dir=PATH")
            self._load_state()
            return
        if has_state:
            raise ConfigError(existing_run_message(self.run_dir))
        if self.config.transfer.enabled and not self.source_task:
            from dqn_transfer.transfer import apply_transfer

            self.transfer_info = apply_transfer(self.config, self.learner, self.game, self.plain,
                                                self.launch_dir)

    @property
    def transferred(self) -> np.ndarray:
        """Which agents started from the transfer source."""
        flags = np.zeros(self.game.num_agents, dtype=bool)
        if self.transfer_info is not None:
            flags[self.transfer_info["targets"]] = True
        return flags

    # ------------------------------------------------------------- checkpoints
    def agent_meta(self, index: int) -> dict[str, Any]:
        game = self.game
        return {
            "algorithm": self.plain["agent"]["algorithm"],
            "agent_index": index,
            "obs_layout": [[name, size] for name, size in game.obs_layout()],
            "num_actions": game.num_actions,
            "network": self.learner.network_meta(),
            # The map as played: ``make_game(**meta["env"])`` rebuilds it from the layout alone.
            "env": {**self.plain["env"], "layout": game.map.layout, "layout_file": None,
                    "size": game.size, "num_treasures": game.num_treasures, "num_traps": game.map.num_traps,
                    "num_agents": game.map.num_agents, "complexity": None, "map_seed": None},
            "mode": self.plain["env"]["mode"],
            "source_task": self.source_task,
            "agent": self.plain["agent"],
            "seed": self.config.seed,
            "steps": self.counters.step,
            "episodes": self.counters.episodes,
            "last_eval": self.last_eval,
            "transfer": self.transfer_info,
        }

    def save_checkpoint(self) -> None:
        """Agent files first (for sharing), then the resume state, which alone is read on resume."""
        from dqn_transfer.checkpoint import save_agent_checkpoint, save_training_state

        self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, np.ndarray] = {}
        for i in range(self.game.num_agents):
            tensors = self.learner.agent_tensors(i)
            save_agent_checkpoint(self.checkpoint_dir / f"agent_{i}.safetensors", tensors, self.agent_meta(i))
            arrays.update({f"agent_{i}/{name}": t.numpy() for name, t in tensors.items()})
        learner_arrays, learner_meta = self.learner.training_state()
        arrays.update({f"learner/{name}": a for name, a in learner_arrays.items()})
        arrays["exchange/returns"] = np.asarray(self.window_returns, dtype=np.float64).reshape(-1, self.game.num_agents)
        for name, column in zip(TRANSITION_FIELDS, zip(*self.shared_transitions)):
            arrays[f"exchange/{name}"] = np.stack(column)
        meta = {
            "counters": self.counters.__dict__,
            "learner": learner_meta,
            "last_eval": self.last_eval,
            "transfer": self.transfer_info,
            "obs_layout": [[name, size] for name, size in self.game.obs_layout()],
            "algorithm": self.plain["agent"]["algorithm"],
            "config": self.plain,  # what resume=true continues with
            "layout": self.game.map.layout,  # the map itself: a layout file may have changed since
        }
        save_training_state(self.checkpoint_dir / TRAINING_STATE, arrays, meta)

    def _load_state(self) -> None:
        import torch

        from dqn_transfer.checkpoint import CheckpointError, load_training_state

        arrays, meta = load_training_state(self.checkpoint_dir / TRAINING_STATE)
        expected_layout = [[name, size] for name, size in self.game.obs_layout()]
        if meta.get("obs_layout") != expected_layout or meta.get("algorithm") != self.plain["agent"]["algorithm"]:
            raise CheckpointError(
                f"{self.checkpoint_dir}: the run was made with algorithm {meta.get('algorithm')} and obs layout "
                f"{meta.get('obs_layout')}; this config gives {self.plain['agent']['algorithm']} and "
                f"{expected_layout}")
        if meta.get("layout") != self.game.map.layout:
            raise CheckpointError(f"{self.checkpoint_dir}: the run was trained on another map:\n"
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
            self.shared_transitions = list(zip(*(arrays[f"exchange/{name}"] for name in TRANSITION_FIELDS)))
        self.last_eval = meta["last_eval"]
        self.transfer_info = meta["transfer"]
        self._truncate_metrics(self.counters.evaluations)
        log.info("resumed %s at step %d (episode %d)", self.run_dir, self.counters.step, self.counters.episodes)

    def _truncate_metrics(self, evaluations: int) -> None:
        """Keep the evaluations the checkpoint counted; the killed run's later ones will be redone.

        By count, not by step: the loop checkpoints *before* evaluating the same step, so a line at
        the checkpoint's step may be one the checkpoint does not know about.
        """
        if not self.metrics_path.exists():
            return
        from dqn_transfer.checkpoint import atomic_write

        lines = [line for line in self.metrics_path.read_text().splitlines() if line.strip()][:evaluations]
        atomic_write(self.metrics_path, "".join(line + "\n" for line in lines).encode())
        self.last_eval_step = json.loads(lines[-1])["step"] if lines else None

    # --------------------------------------------------------------- evaluation
    def run_evaluation(self, logger) -> None:
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
        with self.metrics_path.open("a") as stream:
            stream.write(json.dumps(record) + "\n")
        logger.scalar("eval/team_return", result["team_return"], step)
        logger.scalar("eval/success_rate", result["success_rate"], step)
        log.info("eval step %d: team_return %.1f success_rate %.2f trap_rate %.2f", step,
                 result["team_return"], result["success_rate"], result["trap_rate"])

    # --------------------------------------------------------------------- loop
    def run(self) -> dict[str, Any]:
        from tqdm import tqdm

        from dqn_transfer.logging import RunLogger

        self.prepare()
        config, game, learner, counters = self.config, self.game, self.learner, self.counters
        self.run_dir.mkdir(parents=True, exist_ok=True)
        logger = RunLogger(self.run_dir / "tb", game.num_agents, self.plain,
                           purge_step=counters.step if config.resume else None)
        if self.transfer_info is not None and not config.resume:
            logger.text("transfer/source", json.dumps(self.transfer_info, indent=2))
        if config.total_steps == 0:
            self.save_checkpoint()
            logger.close()
            log.info("total_steps=0: wrote the initial checkpoints to %s", self.checkpoint_dir)
            return {"step": 0, "last_eval": {}}
        if counters.step % config.eval_every == 0 and self.last_eval_step != counters.step:
            self.run_evaluation(logger)  # step 0, or a resumed checkpoint's step whose eval was lost

        env_rng = np.random.default_rng([config.seed, 17])
        if counters.env_rng_state:  # resumed: continue the episode-reset stream where it stopped
            env_rng.bit_generator.state = counters.env_rng_state
        obs = game.reset(env_rng)
        stats = EpisodeStats(game.num_agents)
        window_td, window_q = [], []
        exchange = config.transfer.exchange
        reward_mode = self.plain["env"]["reward_mode"]
        bar = tqdm(total=config.total_steps, initial=counters.step, disable=not config.progress,
                   unit="step", dynamic_ncols=True, file=sys.stderr)
        sps_clock, sps_step = time.perf_counter(), counters.step
        team_return = 0.0
        transferred = self.transferred
        while counters.step < config.total_steps:
            epsilon = epsilons_at(config, counters.step, transferred, counters.exploration_steps)
            live_before = game.live.copy()
            actions = learner.act(obs, live_before, epsilon=epsilon)
            next_obs, rewards, terminated, truncated, info = game.step(actions)
            counters.step += 1
            update = learner.update(obs, actions, rewards, next_obs, terminated, truncated, live_before,
                                    counters.step)
            if exchange is Exchange.shared_replay:
                self.shared_transitions.append((obs, actions, rewards, next_obs, terminated, truncated, live_before))
            obs = next_obs
            stats.add(rewards, live_before, info["trap"])
            team_return += team_return_of(rewards[live_before], reward_mode)
            window_td.append(update["td_loss"])
            window_q.append(update["q_mean"])

            if game.done:
                counters.episodes += 1
                self._log_episode(logger, stats, team_return, counters.step)
                stats.recent_team_returns.append(team_return)
                self.window_returns.append(stats.returns.copy())
                team_return = 0.0
                stats.reset()
                if exchange is not Exchange.none and counters.episodes % config.transfer.exchange_every == 0:
                    self._exchange(logger)
                if counters.step >= counters.next_checkpoint:
                    counters.env_rng_state = env_rng.bit_generator.state
                    self.save_checkpoint()
                    while counters.next_checkpoint <= counters.step:
                        counters.next_checkpoint += config.checkpoint_every
                obs = game.reset(env_rng)

            if counters.step % config.eval_every == 0:
                self.run_evaluation(logger)
            if counters.step % LOG_EVERY == 0 or counters.step == config.total_steps:
                now = time.perf_counter()
                sps = (counters.step - sps_step) / max(now - sps_clock, 1e-9)
                sps_clock, sps_step = now, counters.step
                self._log_training(logger, window_td, window_q, epsilon, sps, counters.step)
                window_td, window_q = [], []
                recent = stats.recent_team_returns
                bar.set_postfix(team_return=f"{np.mean(recent):.1f}" if recent else "-",
                                eps=f"{epsilon.mean():.2f}", sps=f"{sps:.0f}", refresh=False)
                bar.update(counters.step - bar.n)
        bar.close()
        if self.last_eval_step != counters.step:  # not twice when resuming a finished run
            self.run_evaluation(logger)
        counters.env_rng_state = env_rng.bit_generator.state
        self.save_checkpoint()
        logger.close()
        log.info("done: %d steps, %d episodes; last eval %s; checkpoints in %s; watch with "
                 "`tensorboard --logdir %s`", counters.step, counters.episodes, self.last_eval,
                 self.checkpoint_dir, self.run_dir / "tb")
        return {"step": counters.step, "episodes": counters.episodes, "last_eval": self.last_eval}

    def _log_episode(self, logger, stats: EpisodeStats, team_return: float, step: int) -> None:
        logger.agent_scalars("episodic_return", stats.returns, step)
        logger.agent_scalars("episodic_length", stats.lengths, step)
        logger.scalar("team/return", team_return, step)
        logger.scalar("team/treasures_collected", self.game.treasures_collected, step)
        logger.scalar("team/trap_rate", stats.traps / self.game.num_agents, step)

    @staticmethod
    def _log_training(logger, window_td, window_q, epsilon: np.ndarray, sps: float, step: int) -> None:
        with warnings.catch_warnings():  # all-NaN columns (no update yet) are expected and skipped
            warnings.simplefilter("ignore", RuntimeWarning)
            if window_td:
                logger.agent_scalars("td_loss", np.nanmean(np.asarray(window_td, dtype=float), axis=0), step)
                logger.agent_scalars("q_mean", np.nanmean(np.asarray(window_q, dtype=float), axis=0), step)
        logger.scalar("train/epsilon", float(epsilon.mean()), step)
        logger.scalar("train/sps", sps, step)

    def _exchange(self, logger) -> None:
        """Team knowledge exchange (DESIGN §6), once every ``exchange_every`` episodes."""
        from dqn_transfer.transfer import exchange_best, exchange_replay

        if self.config.transfer.exchange is Exchange.best:
            best = exchange_best(self.learner, np.asarray(self.window_returns), self.config.transfer.exchange_tau)
            logger.scalar("team/exchange_best_agent", best, self.counters.step)
        else:
            exchange_replay(self.learner, self.shared_transitions)
            self.shared_transitions.clear()
        self.window_returns.clear()


def train(config: TrainConfig, run_dir: Path, **kwargs) -> dict[str, Any]:
    """Run (or resume) one training run into ``run_dir``; returns a short summary."""
    return Trainer(config, run_dir, **kwargs).run()


def _user_errors() -> tuple[type[Exception], ...]:
    from dqn_transfer.checkpoint import CheckpointError
    from dqn_transfer.transfer_mapping import TransferError

    return ConfigError, CheckpointError, TransferError


# What a resumed run may change; everything else is the run's own saved config.
RESUMABLE_KEYS = ("total_steps", "progress", "checkpoint_every", "device", "threads")


def resume_config(state: Path, cfg: DictConfig, overrides: list[str]) -> TrainConfig:
    """The saved config of the run being resumed, with the command line's resumable overrides.

    ``resume=true hydra.run.dir=DIR`` alone continues the run as it was configured; an override that
    would change what is being learned (``agent.lr=...``, ``agent=sarsa``) is refused by name.
    """
    from omegaconf import OmegaConf

    from dqn_transfer.checkpoint import load_training_state

    from omegaconf.errors import OmegaConfBaseException

    _, meta = load_training_state(state)
    try:
        saved = OmegaConf.merge(OmegaConf.structured(TrainConfig), meta["config"])
    except (KeyError, OmegaConfBaseException) as err:
        raise ConfigError(f"{state}: its saved config does not fit this version of dqn_transfer ({err})") from None
    # Hydra has just written the resume command's composition there; record the run's own instead.
    record = state.parent.parent / ".hydra" / "config.yaml"
    OmegaConf.save(saved, record)
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~")
        if key == "resume" or key.startswith("hydra"):
            continue
        wanted = OmegaConf.select(cfg, key)
        if key in RESUMABLE_KEYS:
            OmegaConf.update(saved, key, wanted)
        elif wanted != (have := OmegaConf.select(saved, key)):
            shown = "" if isinstance(have, DictConfig) else f" ({key}={have})"
            raise ConfigError(f"resume=true: '{override}' differs from the run's own setting{shown}; a resumed "
                              f"run may change only {', '.join(RESUMABLE_KEYS)}")
    saved.resume = True
    OmegaConf.save(saved, record)
    return OmegaConf.to_object(saved)  # type: ignore[return-value]


class RefuseExistingRun(Callback):
    """Hydra callback: refuse a new run in a run directory that holds one *before* Hydra rewrites
    its ``.hydra/`` record (the trainer's own check comes after that)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        run_dir = Path(config.hydra.run.dir)
        if not config.resume and (run_dir / "checkpoints" / TRAINING_STATE).exists():
            print(f"error: {existing_run_message(run_dir)}", file=sys.stderr)
            sys.exit(1)


def log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (e.g. "a layout fixes the map; ignoring ...") as one line of the run's log, not a
    Python warning with a file name and a source line."""
    log.warning("%s", message)


def report_user_error(err: Exception) -> None:
    """One line on stderr and in the run's log file; no traceback for a user's mistake."""
    message = f"error: {err}"
    print(message, file=sys.stderr)
    record = log.makeRecord(log.name, logging.ERROR, __file__, 0, message, None, None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


register_configs()


def main() -> None:
    """Hydra entry point (``python train.py``); user errors end in one line and exit code 1."""
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.utils import get_original_cwd
    from omegaconf import OmegaConf

    @hydra.main(version_base="1.3", config_path=str(Path(__file__).resolve().parent.parent / "conf"),
                config_name="config")
    def _main(cfg: DictConfig) -> float:
        warnings.showwarning = log_warning
        run_dir = Path(HydraConfig.get().runtime.output_dir)
        try:
            state = run_dir / "checkpoints" / TRAINING_STATE
            if cfg.resume and state.exists():
                config = resume_config(state, cfg, HydraConfig.get().overrides.task)
            else:
                config = OmegaConf.to_object(cfg)  # type: ignore[assignment]
            summary = train(config, run_dir, launch_dir=Path(get_original_cwd()))
        except _user_errors() as err:
            report_user_error(err)
            sys.exit(1)
        team_return = summary["last_eval"].get("team_return", math.nan)
        return float(team_return)  # the objective a Hydra sweeper (e.g. Optuna) would optimise

    _main()
