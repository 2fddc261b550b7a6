"""``python -m lossvo.train``: runs :func:`lossvo.training.train.main`."""

from lossvo.training.train import main

if __name__ == "__main__":
    main()
