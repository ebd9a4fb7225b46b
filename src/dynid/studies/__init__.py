"""Studies: reproducible comparisons of the papers (runnable modules)."""

from __future__ import annotations

__all__ = ["draw_seed"]


def draw_seed(base: int, draw: int = 0) -> int:
    """The seed of a study's simulated data in its ``draw``-th repetition.

    Draw 0 is the recorded study: ``base`` itself (the figures in bench/README.md). Any other
    draw repeats the same experiment with other random data: a seed taken from ``(base, draw)``
    by NumPy's ``SeedSequence`` (independent streams for different bases and draws). A finding
    that holds on draw 0 only is a property of that draw, not of the method; running a study on
    other draws (``bench/*.py --draw N``; the tests' ``DYNID_TEST_SEED``) tells the two apart.
    The robots under test (``perturbation_seed``) keep their seeds: another draw is another
    experiment on the same robot."""
    if int(draw) == 0:
        return int(base)
    import numpy as np

    return int(np.random.SeedSequence([int(base), int(draw)]).generate_state(1)[0] % 2**31)
