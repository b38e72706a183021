"""Watching a team play: greedy episodes recorded frame by frame, as a GIF, in the terminal, and as
TensorBoard's evaluation picture.

An episode of T steps is T + 1 :class:`Frame` s: the state after the reset, then after every step.
Each frame is drawn with the agents' trails up to it (:mod:`dqn_transfer.envs.pictures`) and a caption
with the step and the team return so far; the GIF holds every frame of every episode watched, the
terminal replay prints the same frames as text (:func:`~dqn_transfer.envs.game.text_grid`).

Another game (a PettingZoo env, :class:`~dqn_transfer.envs.PettingZooGame`) is recorded as a
:class:`DrawnEpisode`: the env's own RGB frames (``render_mode="rgb_array"``), when its game draws, each
with the same caption; it has no text grid.
"""

from __future__ import annotations

import io
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, TextIO, overload

import numpy as np
from PIL import Image

from dqn_transfer.agents.base import Team
from dqn_transfer.envs import Game, PettingZooGame
from dqn_transfer.envs.game import COLOURS, TreasureHuntGame, text_grid
from dqn_transfer.envs.pictures import agent_colour, captioned, draw_state
from dqn_transfer.evaluation.rollout import (
    EpisodeResult,
    Policy,
    greedy_policy,
    play_episode,
    team_return_of,
)

GIF_FRAME_MS = 250  # the faces' render_fps of 4
GIF_LAST_FRAME_MS = 1500  # a pause on each episode's outcome
GIF_CELL_PX = 40
GIF_MAX_SIDE_PX = 480  # another game's larger frames are scaled down to this side
TENSORBOARD_CELL_PX = 32  # small: the evaluation image is written at every evaluation


class Frame(NamedTuple):
    """The game as it stood after ``step`` joint steps of an episode."""

    step: int
    positions: np.ndarray  # [K, 2] (row, col); a done agent stays where it ended
    live: np.ndarray  # [K] bool
    chest_full: np.ndarray  # [k] bool
    team_return: float  # so far


@dataclass
class RecordedEpisode:
    """One episode as played: its frames, what each agent saw when it acted, and its outcome."""

    game: TreasureHuntGame
    frames: list[Frame]
    observations: list[tuple[np.ndarray, np.ndarray]]  # per step: (obs [K, D], live [K]) the policy acted on
    result: EpisodeResult
    q_values: np.ndarray | None = None  # [T, K, A] the agents' Q-values there, where the player recorded them

    def trails(self, upto: int) -> list[np.ndarray]:
        """Per agent, the cells it stood on in frames 0..``upto`` (``[upto + 1, 2]``)."""
        cells = np.stack([frame.positions for frame in self.frames[: upto + 1]])  # [T, K, 2]
        return [cells[:, agent] for agent in range(cells.shape[1])]


def record_episode(game: TreasureHuntGame, policy: Policy, rng: np.random.Generator) -> RecordedEpisode:
    """Play one episode with ``policy`` (``rng`` draws chest ties), keeping every frame."""
    frames: list[Frame] = []
    observations: list[tuple[np.ndarray, np.ndarray]] = []

    def snapshot(team_return: float) -> None:
        frames.append(Frame(game.steps, game.positions, game.live, game.chest_full, team_return))

    def on_step(transition, info) -> None:
        observations.append((transition.obs, transition.live))
        snapshot(frames[-1].team_return + team_return_of(transition.rewards, transition.live, game.reward_mode))

    result = play_episode(game, policy, rng, on_step=on_step, on_reset=lambda: snapshot(0.0))
    return RecordedEpisode(game, frames, observations, result)


@dataclass
class DrawnEpisode:
    """One episode of another game as played: the env's own RGB frames ``[H, W, 3]`` after the reset and
    after every step (none when the game does not draw, :attr:`PettingZooGame.draws`), the team return
    so far at each of those moments, and its outcome."""

    game: PettingZooGame
    frames: list[np.ndarray]
    returns: list[float]
    result: EpisodeResult


def record_drawn_episode(game: PettingZooGame, policy: Policy, rng: np.random.Generator) -> DrawnEpisode:
    """Play one episode of another game with ``policy``, keeping the env's frame of every state if it draws.

    :param game: the game (made with :meth:`PettingZooGame.drawing` for frames).
    :param policy: the team's policy.
    :param rng: draws the env's reset seed.
    """
    frames: list[np.ndarray] = []
    returns: list[float] = []

    def snapshot(team_return: float) -> None:
        returns.append(team_return)
        if game.draws:
            frames.append(game.frame())

    def on_step(transition, info) -> None:
        snapshot(returns[-1] + team_return_of(transition.rewards, transition.live, game.reward_mode))

    result = play_episode(game, policy, rng, on_step=on_step, on_reset=lambda: snapshot(0.0))
    return DrawnEpisode(game, frames, returns, result)


Watched = RecordedEpisode | DrawnEpisode


@overload
def watch_team(game: TreasureHuntGame, learner: Team, episodes: int, seed: int) -> list[RecordedEpisode]: ...
@overload
def watch_team(game: PettingZooGame, learner: Team, episodes: int, seed: int) -> list[DrawnEpisode]: ...
@overload
def watch_team(game: Game, learner: Team, episodes: int, seed: int) -> list[RecordedEpisode] | list[DrawnEpisode]: ...


def watch_team(game: Game, learner: Team, episodes: int, seed: int) -> list[RecordedEpisode] | list[DrawnEpisode]:
    """``episodes`` greedy episodes; episode i draws its chest ties (another game: its reset seed) and its
    greedy ties from ``(seed, i)``.

    :param game: the treasure hunt, or another game (:class:`DrawnEpisode` s).
    :param learner: the team.
    :param episodes: how many.
    :param seed: seeds the episodes.
    """
    rngs = [np.random.default_rng([seed, i]) for i in range(episodes)]
    if isinstance(game, PettingZooGame):
        return [record_drawn_episode(game, greedy_policy(learner, rng), rng) for rng in rngs]
    return [record_episode(game, greedy_policy(learner, rng), rng) for rng in rngs]


def outcome(episode: Watched) -> str:
    """One line: what the team achieved."""
    r = episode.result
    if isinstance(episode, DrawnEpisode):
        return f"{r.length} steps, team return {r.team_return:.4g}"
    return (
        f"{r.length} steps, team return {r.team_return:g}, "
        f"chests {r.treasures_collected}/{episode.game.num_treasures}, "
        f"trapped agents {round(r.trap_rate * episode.game.num_agents)}/{episode.game.num_agents}"
    )


# ------------------------------------------------------------------------------------ pictures


def frame_caption(episode: RecordedEpisode, index: int, label: str = "") -> list[str]:
    frame, game = episode.frames[index], episode.game
    return [
        f"{label}step {frame.step}/{game.max_steps}",
        f"team return {frame.team_return:g}  full chests {int(frame.chest_full.sum())}/{game.num_treasures}",
    ]


def frame_picture(episode: RecordedEpisode, index: int, label: str = "", cell_px: int = GIF_CELL_PX) -> Image.Image:
    """Frame ``index`` with the trails that led to it."""
    frame = episode.frames[index]
    return draw_state(
        episode.game.map,
        frame.positions,
        frame.live,
        frame.chest_full,
        episode.trails(index),
        frame_caption(episode, index, label),
        cell_px,
    )


def drawn_picture(episode: DrawnEpisode, index: int, label: str = "") -> Image.Image:
    """Frame ``index`` of another game's episode as its env drew it, scaled down to at most
    :data:`GIF_MAX_SIDE_PX` a side, with the step and the team return so far under it.

    :param episode: the episode.
    :param index: the frame (0: after the reset).
    :param label: put before the step, e.g. which episode.
    """
    picture = Image.fromarray(episode.frames[index])
    picture.thumbnail((GIF_MAX_SIDE_PX, GIF_MAX_SIDE_PX))
    caption = [f"{label}step {index}/{episode.result.length}", f"team return {episode.returns[index]:.4g}"]
    return captioned(np.asarray(picture), caption)


def episode_pictures(episodes: Sequence[Watched]) -> Iterable[tuple[Image.Image, int]]:
    """Every frame of every episode, with how long the GIF shows it (ms)."""
    for number, episode in enumerate(episodes, 1):
        label = f"episode {number}/{len(episodes)}  " if len(episodes) > 1 else ""
        for index in range(len(episode.frames)):
            last = index == len(episode.frames) - 1
            picture = (
                drawn_picture(episode, index, label)
                if isinstance(episode, DrawnEpisode)
                else frame_picture(episode, index, label)
            )
            yield picture, GIF_LAST_FRAME_MS if last else GIF_FRAME_MS


def gif_bytes(episodes: Sequence[Watched]) -> bytes:
    """The episodes as one looping GIF: one frame per step plus each episode's first."""
    pictures, durations = zip(*episode_pictures(episodes))
    buffer = io.BytesIO()
    # disposal 1 and optimize off: every frame is kept whole, none merged into its neighbour.
    pictures[0].save(
        buffer,
        format="GIF",
        save_all=True,
        append_images=list(pictures[1:]),
        duration=list(durations),
        loop=0,
        disposal=1,
        optimize=False,
    )
    return buffer.getvalue()


def map_picture(game: TreasureHuntGame, cell_px: int = GIF_CELL_PX) -> Image.Image:
    """The map with every agent on its start and every chest full (the docs' picture of a map)."""
    game.reset(np.random.default_rng(0))
    return draw_state(game.map, game.positions, game.live, game.chest_full, cell_px=cell_px)


# ------------------------------------------------------------------------------------ the terminal


def _coloured(text: str, rgb: tuple[int, int, int]) -> str:
    return f"\x1b[1;38;2;{rgb[0]};{rgb[1]};{rgb[2]}m{text}\x1b[0m"


# The pictures' colours, but a lighter grey for obstacles: the pictures' dark grey is hard to read on a dark terminal.
CELL_COLOURS = {"T": COLOURS["chest_full"], "t": COLOURS["chest_empty"], "X": COLOURS["trap"], "#": (120, 120, 120)}


def frame_text(episode: RecordedEpisode, index: int, colour: bool) -> str:
    """Frame ``index`` as the game's text grid (agents by their digit), in colour for a terminal."""
    frame = episode.frames[index]
    grid = text_grid(episode.game.map, frame.positions, frame.live, frame.chest_full)
    if colour:
        grid = "".join(
            _coloured(ch, agent_colour(int(ch)))
            if ch.isdigit()
            else _coloured(ch, CELL_COLOURS[ch])
            if ch in CELL_COLOURS
            else ch
            for ch in grid
        )
    return grid + "\n" + "  ".join(frame_caption(episode, index))


def replay_in_terminal(episodes: Sequence[RecordedEpisode], stream: TextIO | None = None, fps: float = 4.0) -> None:
    """Print every frame to ``stream`` (default: stdout). On a terminal: in colour, each frame drawn
    over the last at ``fps``; piped: plain frames one after another, at once."""
    stream = stream or sys.stdout
    live_terminal = stream.isatty()
    for number, episode in enumerate(episodes, 1):
        stream.write(f"episode {number}/{len(episodes)}\n")
        for index in range(len(episode.frames)):
            text = frame_text(episode, index, colour=live_terminal)
            if live_terminal and index:
                stream.write(f"\x1b[{text.count(chr(10)) + 1}F\x1b[J")  # back to the frame's first line, clear below
            stream.write(text + "\n" + ("" if live_terminal else "\n"))
            stream.flush()
            if live_terminal:
                time.sleep(1.0 / fps)
        stream.write(outcome(episode) + "\n")


# ------------------------------------------------------------------------------------ TensorBoard


# An evaluation's first episode as TensorBoard shows it: its last frame with every trail, each agent's Q-values there.
EvaluationViews = tuple[np.ndarray, list[np.ndarray]]


def evaluation_views(learner: Team, episode: RecordedEpisode) -> EvaluationViews:
    """What TensorBoard shows of an evaluation: its first episode (recorded as it was played) as its last
    frame with every trail, ``[H, W, 3]`` uint8, and per agent the Q-values of every observation it acted
    on in that episode."""
    picture = frame_picture(episode, len(episode.frames) - 1, cell_px=TENSORBOARD_CELL_PX)
    if not episode.observations:
        return np.asarray(picture), [np.zeros(0)] * episode.game.num_agents
    acting = np.stack([live for _, live in episode.observations])  # [T, K]
    values = episode.q_values
    if values is None:
        values = np.stack([learner.q_values(obs) for obs, _ in episode.observations])  # [T, K, A]
    return np.asarray(picture), [values[acting[:, agent], agent].ravel() for agent in range(acting.shape[1])]
