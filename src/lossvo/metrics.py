"""``python -m lossvo.metrics``: runs :func:`lossvo.evaluation.metrics.main`."""

from lossvo.evaluation.metrics import main

if __name__ == "__main__":
    raise SystemExit(main())
