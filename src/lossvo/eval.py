"""``python -m lossvo.eval``: runs :func:`lossvo.evaluation.eval.main`."""

from lossvo.evaluation.eval import main

if __name__ == "__main__":
    main()
