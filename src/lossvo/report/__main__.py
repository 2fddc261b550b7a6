"""``python -m lossvo.report``: :func:`lossvo.report.cli.main`."""

import sys

from lossvo.report.cli import main

sys.exit(main())
