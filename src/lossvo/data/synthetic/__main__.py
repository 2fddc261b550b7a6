"""``python -m lossvo.data.synthetic``: the command line of :mod:`lossvo.data.synthetic.cli`."""

import sys

from lossvo.data.synthetic.cli import main

if __name__ == "__main__":
    sys.exit(main())
