"""The contract suite's session: collects each case's verdict for the per-category table."""

from __future__ import annotations

import pytest

from tests.contract.run import table

_VERDICTS: dict[str, dict[str, object]] = {}


@pytest.fixture
def contract_verdicts() -> dict[str, dict[str, object]]:
    return _VERDICTS


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _VERDICTS:
        terminalreporter.section("contract: tried and held per area")
        for row in table(_VERDICTS):
            terminalreporter.write_line(row)
