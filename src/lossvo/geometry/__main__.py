"""``python -m lossvo.geometry``: which metric axioms each rotation distance satisfies."""

from lossvo.geometry.axioms import main

main()
