"""sonarmap.stages.kernels.parallel: results in input order from worker processes, as from this one."""

from __future__ import annotations

import math

import pytest

from sonarmap.stages.kernels.parallel import available_cores, ordered_map


@pytest.mark.parametrize("workers", [1, 2])
def test_results_come_in_input_order_whatever_the_number_of_workers(workers: int) -> None:
    items = [30, 1, 25, 2, 20, 3, 15, 4]  # uneven work, so workers finish out of order
    assert list(ordered_map(math.factorial, items, workers)) == [math.factorial(n) for n in items]


def test_an_item_that_fails_raises_its_own_error_in_the_caller() -> None:
    with pytest.raises(ValueError, match="factorial"):
        list(ordered_map(math.factorial, [3, -1, 4], 2))


def test_there_is_at_least_one_core() -> None:
    assert available_cores() >= 1
