"""``python -m dqn_transfer.play RUN_DIR ...``: the ``dqn-transfer-play`` command under its short module
name (the command itself is :mod:`dqn_transfer.cli.play`, the watching :mod:`dqn_transfer.evaluation.watch`)."""

from dqn_transfer.cli.play import run

if __name__ == "__main__":
    run()
