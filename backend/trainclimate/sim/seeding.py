"""Seeds derived from several integers, so that every coach, day and purpose of a seeded run
draws a stream of its own and a run's numbers do not depend on the order it draws them in."""

from __future__ import annotations

import numpy as np


def seed_of(*parts: int) -> int:
    """One 32-bit seed from ``parts`` (numpy's ``SeedSequence``: distinct tuples give
    independent streams).

    Parameters
    ----------
    *parts : int
        Non-negative integers, e.g. a study's seed, a purpose tag, a coach and a day.

    Returns
    -------
    int
    """
    return int(np.random.SeedSequence(list(parts)).generate_state(1)[0])
