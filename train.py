"""Train agents on the treasure hunt: `python train.py [group=option ...] [key=value ...]`.

See README.md and conf/config.yaml for the menu of options; the app is dqn_transfer/cli/train.py.
"""

from dqn_transfer.cli.train import main

if __name__ == "__main__":
    main()
